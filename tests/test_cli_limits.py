"""Commands given absurd values (issue 28): each answers with a clear message and the documented exit
code (2: a bad value; 1: an output that cannot be written), quickly and in bounded memory — never a
traceback, a hang or gigabytes. The real command line as a user types it, then hypothesis over the
value checks themselves."""

from __future__ import annotations

import argparse
import math

import hostile_files as hostile
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.commands import fit_weights, glr, run
from edge_monitor.offline.experiment_design import DesignError, DesignPoint, _validate
from protocol.console import UsageError, library_message


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    rng = np.random.default_rng(0)
    np.savetxt(folder / "big_nominal.csv", rng.normal(size=(200_000, 1)), header="x", comments="", fmt="%.4f")
    np.savetxt(folder / "big_test.csv", rng.normal(size=(200_000, 1)), header="x", comments="", fmt="%.4f")
    np.savetxt(folder / "nominal.csv", rng.normal(size=(300, 1)), header="x", comments="")
    np.savetxt(folder / "test.csv", rng.normal(size=(50, 1)) + 1, header="x", comments="")
    (folder / "sample_1e11.csv").write_text("cycle,sample,speed,torque\n0,0,1,0.1\n0,100000000000,1,0.1\n"
                                            "1,0,1,0.2\n")
    (folder / "deep.toml").write_text(hostile.deep_toml(5000))
    (folder / "deep_tables.toml").write_text(hostile.deep_toml(5000, "table"))
    return folder


CASES = {   # name: (arguments, exit code, what the message says)
    "run --duration nan": (["run", "--link", "virtual:x", "--no-zenoh", "--duration", "nan"], 2, "--duration nan"),
    "run --duration inf": (["run", "--link", "virtual:x", "--no-zenoh", "--duration", "inf"], 2, "--duration inf"),
    "run --idle-stop -1": (["run", "--link", "virtual:x", "--no-zenoh", "--idle-stop", "-1"], 2, "--idle-stop"),
    "run --max-cycles 0": (["run", "--link", "virtual:x", "--no-zenoh", "--max-cycles", "0"], 2, "--max-cycles"),
    "design --seed -1": (["design", "--points", "3", "--seed", "-1"], 2, "--seed -1"),
    "design --points 100000": (["design", "--points", "100000"], 2, "--points"),
    "design --noise-std 1e-300": (["design", "--points", "3", "--noise-std", "1e-300"], 2, "--noise-std"),
    "design --wear 1e300": (["design", "--points", "3", "--wear", "1e300"], 2, "--wear"),
    "glr kde unknown 200k rows": (["glr", "--nominal", "{f}/big_nominal.csv", "--test", "{f}/big_test.csv",
                                   "--density", "kde", "--change-time", "unknown"], 2, "components"),
    "glr gce unknown 200k rows": (["glr", "--nominal", "{f}/big_nominal.csv", "--test", "{f}/big_test.csv",
                                   "--density", "gce", "--change-time", "unknown"], 2, "--density gce"),
    "glr gauss unknown 200k rows": (["glr", "--nominal", "{f}/big_nominal.csv", "--test", "{f}/big_test.csv",
                                     "--density", "gauss", "--change-time", "unknown"], 2, "--window"),
    "glr --bootstrap-draws 1e8": (["glr", "--nominal", "{f}/nominal.csv", "--test", "{f}/test.csv", "--density",
                                   "gauss", "--threshold", "bootstrap", "--bootstrap-draws", "100000000"], 2,
                                  "--bootstrap-draws"),
    "glr a FIFO": (["glr", "--nominal", "{f}/fifo.csv", "--test", "{f}/test.csv"], 2, "FIFO"),
    "fit-weights --temperature 80 30": (["fit-weights", "--simulate", "--temperature", "80", "30"], 2,
                                        "--temperature"),
    "fit-weights --load 1 -1": (["fit-weights", "--simulate", "--load", "1", "-1"], 2, "--load"),
    "fit-weights --cycles 1e8": (["fit-weights", "--simulate", "--cycles", "100000000"], 2, "--cycles"),
    "fit-weights --write-csv /proc/forbidden": (["fit-weights", "--simulate", "--cycles", "3", "--write-csv",
                                                 "/proc/forbidden"], 1, "--write-csv"),
    "fit-weights sample index 1e11": (["fit-weights", "--healthy", "{f}/sample_1e11.csv", "--faulty",
                                       "{f}/sample_1e11.csv"], 2, "sample"),
    "config nested 5000 deep": (["replay", "{f}/none.blf", "--config", "{f}/deep.toml"], 2, "nested too deeply"),
    "config inline tables 5000 deep": (["replay", "{f}/none.blf", "--config", "{f}/deep_tables.toml"], 2,
                                       "nested too deeply"),
    "config a FIFO": (["replay", "{f}/none.blf", "--config", "{f}/fifo.csv"], 2, "FIFO"),
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_an_absurd_value_is_a_clear_error(files, case):
    import os
    fifo = files / "fifo.csv"
    if not fifo.exists():
        os.mkfifo(fifo)
    args, code, words = CASES[case]
    done = hostile.run_measured(hostile.edge_monitor(*[a.format(f=files) for a in args]), timeout=300)
    assert not done.timed_out and done.returncode == code, done.stderr[-2000:]
    assert words in done.stderr and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.max_rss_mb < 1000, done.max_rss_mb


# -- the value checks under hypothesis ------------------------------------------------------------
FLOATS = st.floats(allow_nan=True, allow_infinity=True)


@settings(max_examples=300, deadline=None)
@given(duration=st.none() | FLOATS, idle=st.none() | FLOATS, cycles=st.none() | st.integers(-10**12, 10**12))
def test_run_stop_values(duration, idle, cycles):
    args = argparse.Namespace(duration=duration, idle_stop=idle, max_cycles=cycles)
    try:
        run.check_limits(args)
    except UsageError:
        return
    for value in (duration, idle):
        assert value is None or (math.isfinite(value) and value > 0)
    assert cycles is None or cycles >= 1


@settings(max_examples=300, deadline=None)
@given(points=st.integers(-5, 200), values=st.lists(FLOATS, min_size=8, max_size=8))
def test_design_values(points, values):
    temperature, wear, load_mean, load_std, noise, low, high, separation = values
    try:
        _validate(points, DesignPoint(temperature, wear, load_mean, load_std, noise), low, high, separation)
    except DesignError:
        return
    assert all(math.isfinite(v) for v in values) and 0 < low < high <= 10_000 and 1e-6 <= noise <= 1


@settings(max_examples=300, deadline=None)
@given(n0=st.integers(1, 10**7), n=st.integers(1, 10**7), dim=st.integers(1, 8), k=st.none() | st.integers(1, 10**6),
       density=st.sampled_from(["gauss", "kde", "gce"]), change=st.sampled_from(["known", "unknown"]),
       window=st.none() | st.integers(1, 10**7), draws=st.integers(1, 10**6),
       threshold=st.sampled_from(["asymptotic", "bootstrap"]))
def test_glr_sizes(n0, n, dim, k, density, change, window, draws, threshold):
    """Accepted sizes keep every matrix within MAX_CELLS and the searches within MAX_WORK."""
    args = argparse.Namespace(density=density, change_time=change, window=window, bootstrap_draws=draws,
                              threshold=threshold)
    try:
        glr.check_size(args, n0, n, dim, k)
    except UsageError:
        return
    components = k if k is not None else (1 if density == "gauss" else n0)
    assert (n + n0) * components <= glr.MAX_CELLS
    if change == "unknown":
        assert min(window or n, n) * n * components <= glr.MAX_WORK


@settings(max_examples=300, deadline=None)
@given(cycles=st.integers(-10, 10**9), low=FLOATS, high=FLOATS, load=st.none() | st.tuples(FLOATS, FLOATS),
       wear=FLOATS, seed=st.integers(-10, 10))
def test_fit_weights_simulation_values(cycles, low, high, load, wear, seed):
    args = argparse.Namespace(cycles=cycles, temperature=(low, high), load=load, wear=wear, seed=seed)
    try:
        fit_weights.check_simulation(args)
    except UsageError:
        return
    samples = fit_weights.CycleModel().speed_profile()[0].size
    assert cycles * samples <= fit_weights.MAX_CELLS and -40 <= low < high <= 150 and 0 <= wear <= 100


@settings(max_examples=200, deadline=None)
@given(st.text(), st.integers(1, 400))
def test_a_library_message_becomes_one_printable_line_of_bounded_length(text, limit):
    """pyarrow, cantools and canopen put file contents (control bytes, many lines) into their messages; the
    user gets the first line only, printable, at most ``limit`` characters, and nothing of it is lost but
    the closing full stop."""
    out = library_message(ValueError(text), limit)
    assert out.isprintable() and len(out) <= limit
    first = (text.strip().splitlines() or [""])[0][:limit].rstrip(".")
    assert len(out) == len(first)
    assert all(o == c or (o == "?" and not c.isprintable()) for o, c in zip(out, first))
