"""Designs paid once (splitspec_core/synthesis/design_cache.py): kept in the process and on disk, keyed by content."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

import splitspec_core as ss
from splitspec_core.synthesis import design_cache, designer
from splitspec_core.synthesis.report import design_text

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture
def counted(monkeypatch, tmp_path):
    """The cache on, in a folder of this test's; every real design counted."""
    monkeypatch.setenv("SPLITSPEC_CACHE", str(tmp_path / "designs"))
    design_cache.clear_memory()
    calls = []
    real = designer.design

    def counting(sc, **kw):
        calls.append(sc.name)
        return real(sc, **kw)

    monkeypatch.setattr(designer, "design", counting)
    yield calls, tmp_path / "designs"
    design_cache.clear_memory()


def test_the_same_scenario_is_designed_once_in_a_process(counted):
    calls, _ = counted
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")
    a = ss.simulate(sc, steps=5, seed=1)
    b = ss.simulate(ss.load_scenario(EXAMPLES / "ring10_noise.yaml"), steps=5, seed=2)  # loaded again: same content
    assert calls == ["ring10-noise"]
    assert a.xhat.shape == b.xhat.shape
    faster = dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=0.7))
    ss.design(faster)  # another rate: another design
    assert len(calls) == 2


def test_a_slow_design_is_kept_on_disk_and_read_back_by_another_process(counted, monkeypatch):
    calls, folder = counted
    monkeypatch.setattr(design_cache, "DISK_MIN_SECONDS", 0.0)
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    first = design_cache.cached_design(sc)
    files = list(folder.glob("*.pickle"))
    assert len(files) == 1 and not list(folder.glob(".design-*"))
    design_cache.clear_memory()  # as a new process finds it
    again = design_cache.cached_design(sc)
    assert calls == ["paper-discrete"]
    assert again is not first and design_text(again) == design_text(first)


def test_a_torn_file_is_removed_and_the_design_computed_again(counted, monkeypatch):
    calls, folder = counted
    monkeypatch.setattr(design_cache, "DISK_MIN_SECONDS", 0.0)
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    design_cache.cached_design(sc)
    (path,) = folder.glob("*.pickle")
    path.write_bytes(path.read_bytes()[:100])
    design_cache.clear_memory()
    des = design_cache.cached_design(sc)
    assert calls == ["paper-discrete"] * 2 and des.q == 6
    assert path.exists() and path.stat().st_size > 100  # written again, whole


def test_fast_designs_stay_off_the_disk_and_off_turns_the_cache_off(counted, monkeypatch):
    calls, folder = counted
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    design_cache.cached_design(sc)  # about 10 ms: below DISK_MIN_SECONDS
    assert not folder.exists() or not list(folder.glob("*.pickle"))
    monkeypatch.setenv("SPLITSPEC_CACHE", "off")
    design_cache.clear_memory()
    design_cache.cached_design(sc)
    design_cache.cached_design(sc)
    assert len(calls) == 3


def test_the_disk_keeps_the_newest_files_only(counted, monkeypatch):
    calls, folder = counted
    monkeypatch.setattr(design_cache, "DISK_MIN_SECONDS", 0.0)
    monkeypatch.setattr(design_cache, "DISK_KEEP", 2)
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    for rate in (0.5, 0.6, 0.7):
        design_cache.cached_design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=rate)))
    assert len(list(folder.glob("*.pickle"))) == 2


def test_analyses_computed_after_the_design_are_written_back_at_exit(tmp_path):
    # a real process: designs (kept on disk at once), computes the report's analyses, exits; the file then holds
    # them, so the next process pays neither (the IEEE 14-bus transient constant takes as long as its design)
    import os
    import pickle
    import subprocess
    import sys

    folder = tmp_path / "designs"
    code = ("import splitspec_core as ss\n"
            "from splitspec_core.synthesis import design_cache\n"
            "from splitspec_core.synthesis.report import design_text\n"
            "design_cache.DISK_MIN_SECONDS = 0.0\n"
            f"des = design_cache.cached_design(ss.load_scenario({str(EXAMPLES / 'paper_discrete.yaml')!r}))\n"
            "print(len(des._analyses))\n"
            "design_text(des)\n")
    env = {**os.environ, "SPLITSPEC_CACHE": str(folder)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    (path,) = folder.glob("*.pickle")
    with open(path, "rb") as fh:
        kept = pickle.load(fh)
    assert len(kept._analyses) > int(out.stdout.split()[0])


def test_what_no_design_reads_does_not_design_again_and_the_copy_holds_its_own_scenario(counted, tmp_path):
    # pace measures a copy of the scenario written elsewhere with run.record_every set: the design is the one kept
    calls, _ = counted
    text = (EXAMPLES / "ring10_noise.yaml").read_text()
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")
    first = design_cache.cached_design(sc)
    probe = tmp_path / "probe.yaml"
    assert "run: {steps: 200, seed: 1}" in text
    probe.write_text(text.replace("run: {steps: 200, seed: 1}", "run: {steps: 200, seed: 5, record_every: 3}"))
    other = ss.load_scenario(probe)
    assert other.run.record_every == 3 and other.source != sc.source
    again = design_cache.cached_design(other)
    assert calls == ["ring10-noise"]
    assert again.scenario is other and first.scenario is sc
    assert design_text(again) == design_text(first)
    # a key the design reads (run.dt, design.rate) is designed again
    design_cache.cached_design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=0.7)))
    assert len(calls) == 2
