"""Docs and small errors (#30 item 10): the config and towns tables of docs/environment.md are the
generated ones; NumPy integers are accepted where ints are; near-miss town names get a
suggestion; an unknown suite fails at construction; ``drive``'s progress bar shows whole
numbers."""

from __future__ import annotations

import dataclasses
import json
import re

import gymnasium as gym
import numpy as np
import pytest
from v2xbench.envs.v2x_intersection import V2XIntersectionEnv, parallel_env
from v2xbench.envs.v2x_intersection.core.validation import Rule
from v2xbench.envs.v2x_intersection.sim import docgen
from v2xbench.envs.v2x_intersection.sim.config import EnvConfig, make_config
from v2xbench.envs.v2x_intersection.town import get_town

import v2xbench  # noqa: F401
from v2xbench.cli import main

SMALL = dict(num_vehicles=3, num_parked=2, num_pedestrians=2, num_bicycles=0, route_length=80.0)


# ------------------------------------------------------------------------------ generated tables
def test_config_table_in_the_doc_is_the_generated_one():
    text = docgen.DOC.read_text()
    assert docgen.generated_block(text, "config") == docgen.config_table(), (
        "docs/environment.md's config table is stale: run "
        "python -m v2xbench.envs.v2x_intersection.sim.docgen")
    rows = {r.split("|")[1].strip(" `"): r for r in docgen.config_table().splitlines()[2:]}
    assert list(rows) == [f.name for f in dataclasses.fields(EnvConfig)]
    for name, typ in (("scenario", "str \\| None"), ("suite", "str \\| None"),
                      ("route_index", "int \\| None"), ("seed", "int \\| None"),
                      ("route_step", "int"), ("route_length", "float")):
        assert rows[name].split("|")[2].strip() == f"`{typ}`" or f"`{typ}`" in rows[name], name
    assert "a registered scenario type" in rows["scenario"]
    assert "int in [1, 50] m" in rows["route_step"]


def test_every_field_has_a_meaning_in_the_docstring():
    docs = docgen.field_docs(EnvConfig)
    for f in dataclasses.fields(EnvConfig):
        assert docs.get(f.name, "").strip(), f"EnvConfig.{f.name} has no docstring entry"

    @dataclasses.dataclass
    class Undocumented:
        """A config.

        Attributes:
            a: the first.
        """

        a: int = 0
        b: int = 1

    assert "b" not in docgen.field_docs(Undocumented)


def test_rules_are_described_and_unknown_rules_refused():
    assert docgen.describe_rule(docgen.FIELD_RULES["max_objects"]) == "int in [1, 256] object slots"
    assert docgen.describe_rule(docgen.FIELD_RULES["seed"]) == "`None` or int in [0, 2^63 - 1]"
    with pytest.raises(TypeError, match="Rule"):
        docgen.describe_rule(Rule())


def test_towns_table_matches_v2xbench_towns(capsys):
    text = docgen.DOC.read_text()
    assert docgen.generated_block(text, "towns") == docgen.towns_table()
    assert main(["towns"]) == 0
    printed = capsys.readouterr().out.splitlines()
    doc_rows = [[c.strip(" *") for c in r.split("|")[1:-1]]
                for r in docgen.generated_block(text, "towns").splitlines()[2:]]
    assert len(printed) == len(doc_rows) == 7
    for line, (town, split, template, seed, _size, lanes, junctions, crosswalks, buildings) in zip(
            printed, doc_rows):
        got = dict(re.findall(r"(\w+)=\s*(\w+)", line))
        assert line.split()[:2] == [town, split]
        assert (got["template"], got["seed"], got["lanes"], got["junctions"], got["crosswalks"],
                got["buildings"]) == (template, seed, lanes, junctions, crosswalks, buildings)
    town12 = next(r for r in doc_rows if r[0] == "Town12")
    assert town12[1:3] == ["test", "metro2"]
    assert "Town12 is a `metro2` town" in text


def test_check_mode_finds_a_stale_table(tmp_path, capsys):
    doc = tmp_path / "env.md"
    text = docgen.DOC.read_text()
    doc.write_text(text.replace("| `seed` |", "| `seeds` |"))
    assert docgen.main(["--doc", str(doc), "--check"]) == 1
    assert "stale tables" in capsys.readouterr().out and "seeds" in doc.read_text()
    assert docgen.main(["--doc", str(doc)]) == 0
    assert doc.read_text() == text
    assert docgen.main(["--doc", str(doc), "--check"]) == 0
    doc.write_text("# no tables\n")
    with pytest.raises(ValueError, match="generated:config"):
        docgen.main(["--doc", str(doc)])


# ------------------------------------------------------------------------------ small errors
def test_numpy_integers_are_accepted_where_ints_are():
    cfg = make_config(seed=np.int64(3), suite="train", route_index=np.int32(1),
                      max_steps=np.uint16(40), num_vehicles=np.int8(3), route_length=np.float32(80))
    assert (type(cfg.seed), type(cfg.route_index), type(cfg.max_steps)) == (int, int, int)
    assert type(cfg.route_length) is float
    json.dumps(dataclasses.asdict(cfg))  # NumPy scalars would not serialize
    a = V2XIntersectionEnv(seed=np.int64(3), **SMALL)
    b = V2XIntersectionEnv(seed=3, **SMALL)
    oa, _ = a.reset()
    ob, _ = b.reset()
    assert all(np.array_equal(oa[k], ob[k]) for k in oa)
    oa, _ = a.reset(seed=np.int64(4))  # Gymnasium itself wants a Python int
    ob, _ = b.reset(seed=4)
    assert all(np.array_equal(oa[k], ob[k]) for k in oa)
    vec = gym.make_vec("V2XIntersection-v0", num_envs=2, vectorization_mode="vector_entry_point",
                       **SMALL)
    vec.reset(seed=np.int64(5))
    parallel_env(seed=np.int32(2), **SMALL).reset(seed=np.int64(1))
    with pytest.raises(ValueError, match="expected an int"):
        make_config(num_vehicles=np.float64(3.0))


@pytest.mark.parametrize("name", ["town01", "TOWN01", "Town1", "Twon01"])
def test_near_miss_town_names_get_a_suggestion(name):
    with pytest.raises(ValueError, match=r"did you mean 'Town01'\?"):
        make_config(town=name)
    with pytest.raises(ValueError, match=r"did you mean 'Town01'\?"):
        get_town(name)
    with pytest.raises(ValueError, match=r"did you mean 'Town01'\?"):
        V2XIntersectionEnv(town=name)


def test_a_far_town_name_gets_no_suggestion():
    with pytest.raises(ValueError) as e:
        make_config(town="Springfield")
    assert "did you mean" not in str(e.value) and "Town12" in str(e.value)


def test_unknown_suite_fails_at_construction():
    for make in (V2XIntersectionEnv, parallel_env):
        with pytest.raises(ValueError, match="suite: unknown suite 'trian'; known: test50, train"):
            make(suite="trian")


def test_drive_progress_bar_shows_whole_numbers(tmp_path, capsys):
    """``drive`` printed ``83.79999999999964/100`` (float steps summed by tqdm)."""
    assert main(["drive", "--route-length", "30", "--sensors-every", "0", "--frame-every", "100",
                 "--size", "32", "--out", str(tmp_path / "d")]) == 0
    err = capsys.readouterr().err
    counts = re.findall(r"\| *([0-9.]+)/100 ", err)
    assert len(counts) >= 2 and counts[-1] != "0"
    assert all(re.fullmatch(r"\d+", c) for c in counts), counts
