"""The command line as a user meets it on first use: every option of every
subcommand has a help text, every ``--help`` lists the exit codes, and ``fem-rmpm mc``
takes ``--set KEY=VALUE`` and ``--case SPEC`` like ``run`` takes ``--set``, with the
change recorded in the campaign's identity (``campaign.json``)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from fem_rmpm import cli

DATA = Path(__file__).resolve().parent / "data"
TINY = DATA / "mc_tiny.toml"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("fem-rmpm has no subcommands")


def test_every_option_of_every_subcommand_has_help():
    parser = cli.build_parser()
    subs = _subparsers(parser)
    assert {"run", "fem", "mc", "field"} <= set(subs)
    missing = []
    for name, sp in [("fem-rmpm", parser), *subs.items()]:
        for action in sp._actions:
            if isinstance(action, argparse._SubParsersAction):
                continue
            if not action.help or action.help == argparse.SUPPRESS or len(action.help) < 8:
                missing.append(f"{name} {'/'.join(action.option_strings) or action.dest}")
    assert not missing, f"options without help text: {missing}"


@pytest.mark.parametrize("argv", [[], ["run"], ["fem"], ["mc"], ["field"], ["report"]])
def test_help_lists_the_exit_codes(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main([*argv, "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "exit codes:" in text
    for code, what in (("0", "success"), ("2", "bad input"), ("3", "simulation failed"),
                       ("130", "interrupted")):
        assert any(line.split()[:1] == [code] and what in line
                   for line in text.splitlines()), (code, text)


def test_mc_set_and_case_recorded_in_campaign_identity(tmp_path, capsys, dask_scheduler):
    """``mc --set`` and ``--case`` on the tiny scene (on the reference slope the same
    command reads ``fem-rmpm mc --set solver.t_end=5 --case xi=12 -n 2``): the campaign
    runs the one case with the changed end time, campaign.json records it, and the same
    directory with another --set is refused (exit 2, nothing changed)."""
    out = tmp_path / "mc"
    argv = ["mc", str(TINY), "--set", "solver.t_end=0.5", "--case", "xi=12", "-n", "2",
            "--scheduler", dask_scheduler, "--quiet", "--out", str(out)]
    assert cli.main(argv) == 0
    camp = json.loads((out / "campaign.json").read_text())
    assert [c["name"] for c in camp["cases"]] == ["xi12"]
    scene = camp["cases"][0]["scene"]
    assert scene["solver"]["t_end"] == 0.5
    assert scene["random_field"]["anisotropy"] == 12.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cases"][0]["finished"] == 2
    records = sorted((out / "records").glob("realization_*.json"))
    assert len(records) == 2
    for r in records:
        rec = json.loads(r.read_text())
        assert rec["status"] == "ok" and rec["simulated_time"] <= 0.5 + 1e-9
    capsys.readouterr()
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    argv[3] = "solver.t_end=0.6"
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "solver.t_end" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("argv, words", [
    (["--case", "xi"], ["case 'xi'", "homogeneous"]),
    (["--case", "xi=12", "--case", "xi=12"], ["unique"]),
    (["--set", "solver.t_end"], ["--set", "KEY=VALUE"]),
    (["--set", "solver.nonsense=1"], ["solver.nonsense"]),
])
def test_mc_bad_set_or_case_is_one_line_exit_2(tmp_path, capsys, argv, words):
    out = tmp_path / "mc"
    assert cli.main(["mc", str(TINY), *argv, "-n", "1", "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    for w in words:
        assert w in err, (w, err)
    assert not out.exists()


def test_mc_fs_and_fs_only_together_are_one_clear_error(tmp_path, capsys):
    """``mc --fs --fs-only`` is exit 2 with one line; nothing is written."""
    out = tmp_path / "c"
    rc = cli.main(["mc", str(Path(__file__).parent / "data" / "mc_tiny.toml"), "--fs",
                   "--fs-only", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "--fs-only" in err
    assert not out.exists()
