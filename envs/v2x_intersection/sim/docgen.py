"""The generated tables of ``docs/environment.md``: made from the code, so they cannot go stale.

- ``config``: one row per :class:`~.config.EnvConfig` field (name, type annotation, default, the
  meaning from the class docstring's ``Attributes:`` and the rule of ``config.FIELD_RULES``);
- ``towns``: one row per named town, the figures ``v2xbench towns`` prints.

Each table sits between ``<!-- generated:NAME -->`` and ``<!-- /generated:NAME -->`` in the doc.
``python -m v2xbench.envs.v2x_intersection.sim.docgen`` rewrites them; ``--check`` only says whether
they are current (exit 1 if not); ``tests/sim/test_docs_config.py`` fails when they are stale.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import sys
from collections.abc import Callable
from pathlib import Path

from ..core.validation import Bool, Check, Choice, Float, Int, OrNone, Rule, Text
from .config import FIELD_RULES, EnvConfig

#: the doc these tables live in (repository layout: envs/v2x_intersection/sim/docgen.py)
DOC = Path(__file__).resolve().parents[3] / "docs" / "environment.md"


def field_docs(cls: type = EnvConfig) -> dict[str, str]:
    """``name: text`` of the ``Attributes:`` section of ``cls``'s docstring, one line each (an
    entry naming several fields, ``a, b: text``, gives each the text)."""
    doc = inspect.cleandoc(cls.__doc__ or "")
    if "Attributes:" not in doc:
        raise ValueError(f"{cls.__name__}: docstring has no 'Attributes:' section")
    out: dict[str, str] = {}
    names: list[str] = []
    for line in doc.split("Attributes:", 1)[1].splitlines():
        if not line.strip():
            continue
        m = re.fullmatch(r" {4}([\w, ]+): (.*)", line)
        if m:
            names = [n.strip() for n in m.group(1).split(",")]
            for n in names:
                out[n] = m.group(2).strip()
        elif line.startswith(" " * 8) and names:
            for n in names:
                out[n] += " " + line.strip()
        else:
            break
    return out


def _md(text: str) -> str:
    """Docstring markup as Markdown table text: ``x`` and :role:`x` -> `x`, pipes escaped."""
    text = re.sub(r":\w+:`~?\.?([^`]+)`", r"`\1`", text)
    return text.replace("``", "`").replace("|", "\\|")


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def _why(why: str) -> str:
    return f" ({why})" if why else ""


def _num(x: float) -> str:
    """A bound as written by hand: ``30`` not ``30.0``, ``2^63 - 1`` not its 19 digits."""
    if isinstance(x, float):
        return f"{x:g}"
    if x >= 2**31 and (x + 1).bit_count() == 1:
        return f"2^{(x + 1).bit_length() - 1} - 1"
    return str(x)


def describe_rule(rule: Rule) -> str:
    """What a ``validation`` rule accepts, in words (Markdown)."""
    if isinstance(rule, OrNone):
        return f"`None` or {describe_rule(rule.rule)}"
    if isinstance(rule, Int):
        return f"int in [{_num(rule.lo)}, {_num(rule.hi)}]{_unit(rule.unit)}{_why(rule.why)}"
    if isinstance(rule, Float):
        lo = "(" if rule.lo_open else "["
        return f"number in {lo}{_num(rule.lo)}, {_num(rule.hi)}]{_unit(rule.unit)}{_why(rule.why)}"
    if isinstance(rule, Bool):
        return "`True` or `False`"
    if isinstance(rule, Choice):
        return "one of " + ", ".join(f"`{c!r}`" for c in rule.choices) + _why(rule.why)
    if isinstance(rule, Text):
        what = f": {rule.what}" if rule.what else ""
        return f"string of 1-{rule.max_len} characters{what}"
    if isinstance(rule, Check):
        return rule.what
    raise TypeError(f"describe_rule: no description for rule type {type(rule).__name__}")


def config_table() -> str:
    """The Markdown table of every ``EnvConfig`` field."""
    docs = field_docs(EnvConfig)
    rows = ["| field | type | default | meaning | accepted values |", "|---|---|---|---|---|"]
    for f in dataclasses.fields(EnvConfig):
        if f.name not in docs:
            raise ValueError(f"EnvConfig.{f.name}: no entry in the class docstring's Attributes")
        if f.name not in FIELD_RULES:
            raise ValueError(f"EnvConfig.{f.name}: no rule in config.FIELD_RULES")
        typ = str(f.type).replace("|", "\\|")
        rows.append(f"| `{f.name}` | `{typ}` | `{f.default!r}` | {_md(docs[f.name])} | "
                    f"{_md(describe_rule(FIELD_RULES[f.name]))} |")
    return "\n".join(rows)


def town_rows() -> list[dict]:
    """The figures of each named town, as ``v2xbench towns`` prints them."""
    from ..town import NAMED_TOWNS, TEST_TOWNS, get_town

    rows = []
    for name, (template, seed, size) in NAMED_TOWNS.items():
        t = get_town(name)
        rows.append({"town": name, "split": "test" if name in TEST_TOWNS else "train",
                     "template": template, "seed": seed, "size": size, "lanes": len(t.lanes),
                     "junctions": len(t.junctions), "crosswalks": len(t.crosswalks),
                     "buildings": len(t.buildings)})
    return rows


def towns_table() -> str:
    """The Markdown table of the named towns."""
    rows = town_rows()
    keys = list(rows[0])
    out = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        cells = [f"**{v}**" if k == "split" and v == "test" else str(v) for k, v in r.items()]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


#: table name -> generator
TABLES: dict[str, Callable[[], str]] = {"config": config_table, "towns": towns_table}


def _span(name: str) -> re.Pattern:
    return re.compile(rf"(<!-- generated:{name}[^>]*-->\n)(.*?)(<!-- /generated:{name} -->)", re.S)


def render(text: str) -> str:
    """``text`` (the doc) with every generated table replaced by its current version."""
    for name, make in TABLES.items():
        span = _span(name)
        if not span.search(text):
            raise ValueError(f"the doc has no '<!-- generated:{name} -->' ... "
                             f"'<!-- /generated:{name} -->' block")
        table = make()
        text = span.sub(lambda m, t=table: m.group(1) + t + "\n" + m.group(3), text)
    return text


def generated_block(text: str, name: str) -> str:
    """The table currently in the doc's ``name`` block (without the markers)."""
    m = _span(name).search(text)
    if m is None:
        raise ValueError(f"the doc has no generated:{name} block")
    return m.group(2).rstrip("\n")


def main(argv: list[str] | None = None) -> int:
    """Rewrite (or with ``--check`` only compare) the generated tables of the doc."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--doc", type=Path, default=DOC, help="the Markdown file (default: %(default)s)")
    p.add_argument("--check", action="store_true", help="exit 1 if a table is stale; write nothing")
    args = p.parse_args(argv)
    text = args.doc.read_text()
    new = render(text)
    if args.check:
        stale = [n for n in TABLES if generated_block(text, n) != generated_block(new, n)]
        print(f"stale tables in {args.doc}: {', '.join(stale)}" if stale else "up to date")
        return 1 if stale else 0
    if new != text:
        from v2xbench.files import atomic_write_text

        atomic_write_text(args.doc, new)
        print(f"updated {args.doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
