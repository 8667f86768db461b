"""``fgcd bench soak``: the resource samples, the growth slope, the summary keys and a tiny soak."""

import os
import tempfile
import threading

import numpy as np
import pytest

from fgcd_cli.bench.soak.main import private_tempdir, run
from fgcd_cli.bench.soak.sample import (
    ResourceSample,
    TempBaseline,
    growth_per_revisit,
    proc_status_mb,
    sample_resources,
    summarize_samples,
)


def _sample(index, rss, *, phase="quick", fds=10, threads=5, tmp=0, hwm=None, afd=float("nan")):
    return ResourceSample(
        index=index,
        phase=phase,
        seconds=1.0,
        rss_mb=rss,
        hwm_mb=hwm or rss + 1.0,
        threads_native=threads,
        threads_python=2,
        fds=fds,
        tmp_left=tmp,
        afd_px=afd,
    )


def test_growth_is_the_least_squares_slope_after_the_warmup():
    rng = np.random.default_rng(0)
    slope = 0.25
    warm = [100.0, 180.0, 230.0]  # libraries and caches loading: left out
    noise = rng.normal(0.0, 0.5, 40)
    values = warm + list(250.0 + slope * np.arange(40) + noise)
    expected = np.polyfit(np.arange(40), 250.0 + slope * np.arange(40) + noise, 1)[0]
    assert growth_per_revisit(values, warmup=3) == pytest.approx(expected)
    # the noise's own slope bounds the error: 0.5 MB over 40 points
    assert abs(growth_per_revisit(values, warmup=3) - slope) < 3 * 0.5 / np.sqrt(np.sum((np.arange(40) - 19.5) ** 2))
    assert growth_per_revisit([5.0] * 20, warmup=2) == pytest.approx(0.0)
    # a flat series after a warm-up step has no slope; including the step would show one
    assert growth_per_revisit(warm + [250.0] * 10, warmup=3) == pytest.approx(0.0, abs=1e-9)
    assert growth_per_revisit(warm + [250.0] * 10, warmup=0) > 0


def test_growth_needs_two_points_after_the_warmup():
    assert growth_per_revisit([1.0, 2.0, 3.0], warmup=2) == 0.0
    assert growth_per_revisit([], warmup=0) == 0.0
    assert growth_per_revisit([1.0, float("nan"), 3.0], warmup=0) == pytest.approx(2.0)


def test_summary_fits_each_phase_and_takes_the_maxima():
    samples = [_sample(0, 90.0, phase="setup", fds=8, threads=3)]
    samples += [
        _sample(k, 200.0 + 2.0 * k + 30.0 * (k == 6), fds=10 + (k == 4), threads=6 + (k == 2), afd=0.5 + 0.01 * k)
        for k in range(1, 7)
    ]
    samples += [_sample(k, 400.0 - k, phase="changes", tmp=1 if k == 8 else 0, hwm=900.0) for k in range(7, 10)]
    s = summarize_samples(samples, warmup=1)
    # revisits 2..6 after the warm-up: 2 MB each, and a one-off step of 30 MB at the last
    assert s["rss_growth_mb_per_revisit"] == pytest.approx(np.polyfit(np.arange(5), [204, 206, 208, 210, 242], 1)[0])
    assert s["rss_largest_step_mb"] == pytest.approx(32.0)
    assert s["afd_px_max"] == pytest.approx(0.56) and s["afd_growth_px_per_revisit"] == pytest.approx(0.01)
    # the change revisits' own slope, after their first (which compares every earlier visit)
    assert s["rss_growth_mb_per_change_revisit"] == pytest.approx(-1.0)
    assert s["rss_peak_mb"] == 900.0
    assert s["threads_max"] == 7 and s["fds_max"] == 11 and s["fds_end"] == 10
    assert s["tmp_files_left"] == 0 and s["tmp_files_left_max"] == 1
    assert s["rss_start_mb"] == 202.0 and s["rss_end_mb"] == 391.0
    assert samples[1].to_dict()["afd_px"] == 0.51 and samples[-1].to_dict()["afd_px"] is None


def test_proc_status_reads_kilobytes_as_megabytes():
    text = "Name:\tpython\nVmHWM:\t  204800 kB\nVmRSS:\t  102400 kB\nThreads:\t7\n"
    assert proc_status_mb(text, "VmRSS") == pytest.approx(102400 * 1024 / 1e6)
    assert proc_status_mb(text, "VmHWM") == pytest.approx(204800 * 1024 / 1e6)
    assert np.isnan(proc_status_mb(text, "VmSwap"))


def test_sample_counts_this_process_threads_descriptors_and_new_temporaries(tmp_path):
    campaign = tmp_path / "campaign"
    (campaign / "stations" / "s").mkdir(parents=True)
    (campaign / "stations" / "s" / ".tmp-old").mkdir()  # there before: not this run's
    with private_tempdir(tmp_path / "tmp") as tmp:
        assert tempfile.gettempdir() == str(tmp) and os.environ["TMPDIR"] == str(tmp)
        baseline = TempBaseline.take(campaign)
        before = sample_resources(index=0, phase="setup", seconds=0.0, baseline=baseline)
        stop = threading.Event()
        worker = threading.Thread(target=stop.wait)
        worker.start()
        kept = [[k] for k in range(50000)]  # 50,000 lists still referenced: tracked objects, as a leak's
        handle = open(tmp_path / "held", "w")
        fd, _ = tempfile.mkstemp()  # a temporary file left (its descriptor too)
        (campaign / "stations" / "s" / ".tmp-new").write_text("x")
        try:
            after = sample_resources(index=1, phase="quick", seconds=0.0, baseline=baseline)
        finally:
            stop.set()
            worker.join()
            handle.close()
            os.close(fd)
        assert after.threads_native == before.threads_native + 1
        assert after.threads_python == before.threads_python + 1
        assert after.fds == before.fds + 2
        assert after.tmp_left == 2 and before.tmp_left == 0
        # other threads of the test run free a few objects meanwhile (62 seen in a full run): 10 % of slack
        assert after.python_objects >= before.python_objects + 0.9 * len(kept)
        assert baseline.left()[-1] == "stations/s/.tmp-new"
    assert tempfile.gettempdir() != str(tmp)
    assert before.rss_mb > 0 and before.hwm_mb >= before.rss_mb


@pytest.mark.slow
def test_tiny_soak_verifies_every_visit_and_reads_the_history_back(tmp_path):
    data = run(revisits=2, change_revisits=1, out=tmp_path / "soak")
    s = data["summary"]
    assert s["revisits"] == 3 and s["change_revisits"] == 1
    assert s["visits_verified"] == 3, [x["detail"] for x in data["samples"]]
    assert s["history_complete"] and data["history"]["listed"] == 3
    assert s["tmp_files_left"] == 0, data["tmp_left"]
    assert s["threads_max"] >= s["threads_python_max"] >= 1 and s["fds_max"] > 0 and s["rss_peak_mb"] > 0
    assert [x["index"] for x in data["samples"]] == [0, 1, 2, 3]
    lines = (tmp_path / "soak" / "samples.jsonl").read_text().splitlines()
    assert len(lines) == 4
    # the change revisit's report compared every visit
    assert data["history"]["analysed"] == 3
