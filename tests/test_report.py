"""The campaign report (``report.html``): content, escaping, and a real headless browser.

The browser test opens the report of a tiny campaign (``tests/data/mc_tiny.toml``, 2
realizations, one kept VTK) in headless Chromium: the page renders (a screenshot is
written), every embedded image decodes (the page's own script counts them into
``<body data-images-loaded="k/n">``) and no script or resource error fired
(``data-errors="0"``).  In CI (``CI`` set) a missing browser fails the test; on a
developer machine without Chromium it is skipped with the reason.
"""
from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from fem_rmpm.campaign.report import ReportError, report_html, write_report
from fem_rmpm.cli import main


def _browser() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        exe = shutil.which(name)
        if exe:
            return exe
    if os.environ.get("CI"):
        pytest.fail("CI: no headless Chromium found (.ci/run installs the Debian package "
                    "`chromium`); the report's browser test must not be skipped in CI")
    pytest.skip("no Chromium on this machine (apt-get install chromium)")


@pytest.fixture(scope="module")
def campaign(mc_tiny_campaign, tmp_path_factory) -> Path:
    """This module's copy of the shared finished campaign of ``tests/data/mc_tiny.toml``
    (``fem-rmpm mc -n 2 --workers 1``, conftest.py): its tests rewrite the report."""
    out = tmp_path_factory.mktemp("report") / "mc"
    shutil.copytree(mc_tiny_campaign, out)
    return out


def test_mc_writes_the_report(campaign):
    """``fem-rmpm mc`` ends by writing report.html beside summary.json."""
    page = (campaign / "report.html").read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>") and "mc_tiny" in page


def test_report_command(campaign, tmp_path, capsys):
    """``fem-rmpm report DIR`` (the command line's ``main``, in this process) rewrites the
    page; a directory without a campaign is exit 2, one line, and nothing is written
    there."""
    (campaign / "report.html").unlink()
    code = main(["report", str(campaign)])
    err = capsys.readouterr().err
    assert code == 0 and (campaign / "report.html").is_file(), err
    code = main(["report", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    assert "no summary.json" in err and list(tmp_path.iterdir()) == []


def test_report_content(campaign):
    """The page holds the provenance, the per-case statistics of ``summary.json`` and every
    PNG of the campaign directory, embedded (no file reference for images)."""
    write_report(campaign)
    page = (campaign / "report.html").read_text(encoding="utf-8")
    summary = json.loads((campaign / "summary.json").read_text())
    case = summary["cases"][0]
    assert f"{case['ok']} ok of {case['requested']}" in page
    assert str(summary["campaign_seed"]) in page
    pngs = sorted(p.name for p in campaign.glob("*.png"))
    assert pngs, "the campaign wrote no figure"
    assert page.count("data:image/png;base64,") >= len(pngs)
    assert not re.search(r'<img src="(?!data:)', page), "an image refers to a file"
    assert 'href="vtk/realization_00000/particles.pvd"' in page
    machine = summary["this_run"]["machine"]          # the machine of the campaign process
    assert f"machine of the last command</td><td>{html.escape(machine['cpu_model'])}" in page
    assert f"{machine['usable_cores']} of {machine['logical_cores']} cores usable" in page
    ran_on = summary["worker_machines"]         # the machines the records name, counted
    assert sum(m["runs"] for m in ran_on) == len(list((campaign / "records").glob("*.json")))
    first = ran_on[0]
    assert (f"realizations ran on</td><td>{html.escape(first['host'])} "
            f"({html.escape(first['cpu_model'])}): {first['runs']}") in page


def test_report_escapes_messages(campaign, tmp_path):
    """A numerical failure's message is shown, escaped (a record is data, never markup)."""
    work = tmp_path / "mc"
    shutil.copytree(campaign, work)
    rec = work / "records" / "realization_00001.json"
    doc = json.loads(rec.read_text())
    doc.update(status="failed", error="<script>alert(1)</script> at step 7")
    rec.write_text(json.dumps(doc))
    page = report_html(work)
    assert "&lt;script&gt;alert(1)&lt;/script&gt; at step 7" in page
    assert "<script>alert(1)" not in page


def test_report_refuses_a_directory_without_a_campaign(tmp_path):
    with pytest.raises(ReportError, match="no summary.json"):
        report_html(tmp_path)


def test_report_in_headless_browser(campaign, tmp_path):
    """Chromium renders the page: screenshot written, all images decoded, no errors."""
    exe = _browser()
    page = write_report(campaign)
    shot = tmp_path / "report.png"
    base = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1400,2000"]
    r = subprocess.run(base + [f"--screenshot={shot}", page.resolve().as_uri()],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and shot.is_file() and shot.stat().st_size > 10_000, r.stderr
    r = subprocess.run(base + ["--enable-logging=stderr", "--v=0", "--dump-dom",
                               page.resolve().as_uri()],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    body = re.search(r"<body[^>]*>", r.stdout)
    assert body, r.stdout[:500]
    loaded = re.search(r'data-images-loaded="(\d+)/(\d+)"', body.group(0))
    assert loaded and loaded.group(1) == loaded.group(2) and int(loaded.group(2)) >= 4, \
        body.group(0)
    assert 'data-errors="0"' in body.group(0), body.group(0)
    assert "Uncaught" not in r.stderr, r.stderr


def test_report_shows_a_subset_campaign(campaign, tmp_path):
    """A subset-simulation summary gets its own section: estimate, cost and levels."""
    work = tmp_path / "mc"
    shutil.copytree(campaign, work)
    doc = json.loads((work / "summary.json").read_text())
    doc["subset"] = {"response": "runout_distance", "failure": "run-out > 3 m",
                     "probability": 1.23e-4, "cov": 0.31, "p0": 0.1,
                     "samples_per_level": 1000, "total_runs": 3700,
                     "crude_equivalent_runs": 84000, "failed_runs": 0, "notes": [],
                     "levels": [{"level": 0, "threshold_response": 1.5,
                                 "conditional_probability": 0.1, "cov": 0.09, "gamma": 0.0,
                                 "acceptance": None, "runs": 1000}]}
    (work / "summary.json").write_text(json.dumps(doc))
    page = report_html(work)
    assert "<h2>Subset simulation</h2>" in page and "run-out &gt; 3 m" in page
    assert "0.000123" in page and "84000" in page
