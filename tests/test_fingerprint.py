"""``v2xbench fingerprint``: the same runs hash the same, a changed run hashes differently, and
``--check`` reports a difference with exit code 1."""

import argparse
import json

from v2xbench.benchmarks import fingerprint as fp


def test_hash_is_repeatable_and_sensitive():
    cfg = dict(town="Town01", num_vehicles=5, num_pedestrians=2)
    a = fp.gym_run(cfg, 30)
    assert fp.gym_run(cfg, 30) == a
    assert fp.gym_run(cfg, 30, seed=1) != a
    assert fp.gym_run(cfg, 31) != a
    assert fp.gym_run(cfg, 30, actions="random") != a


def test_check_flags_a_difference(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(fp, "CONFIGS", {"tiny": lambda: fp.gym_run(dict(town="Town02", num_vehicles=3), 10),
                                        "tiny torch": lambda: fp.torch_run(2, 5)})
    saved = tmp_path / "fp.json"
    args = argparse.Namespace(only=None, out=str(saved), check=None)
    assert fp.run(args) == 0
    assert set(json.loads(saved.read_text())) == {"tiny", "tiny torch", fp.PLATFORM_KEY}
    assert json.loads(saved.read_text())[fp.PLATFORM_KEY] == fp.platform_record()
    assert fp.run(argparse.Namespace(only="torch", out=None, check=str(saved))) == 0
    saved.write_text(json.dumps({"tiny": "0" * 16}))  # an older file, with no platform record
    assert fp.run(argparse.Namespace(only=None, out=None, check=str(saved))) == 1
    err = capsys.readouterr().err
    assert "DIFFERENT: tiny" in err and "NumPy" not in err
    # saved on a machine where NumPy dispatched to other SIMD code: --check says so
    saved.write_text(json.dumps({"tiny": "0" * 16, fp.PLATFORM_KEY: {"numpy": "0.0", "simd": ["NONE"]}}))
    assert fp.run(argparse.Namespace(only=None, out=None, check=str(saved))) == 1
    assert "dispatching to ['NONE']" in capsys.readouterr().err
