"""``edge-monitor glr`` used as a user would: real CSV files, the installed console script."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from edge_monitor import cli

EDGE_MONITOR = Path(sys.executable).parent / "edge-monitor"
SYSTEM_FIELDS = {"statistic", "threshold", "alarm", "delta", "miss_probability", "components"}


def write_csv(path: Path, header: str, rows: np.ndarray) -> Path:
    np.savetxt(path, rows, delimiter=",", header=header, comments="")
    return path


def run_cli(*args: str) -> subprocess.CompletedProcess:
    """The installed console script in a real process (slow to start: used for a few tests)."""
    return subprocess.run([str(EDGE_MONITOR), "glr", *args], capture_output=True, text=True, timeout=120)


def run_in_process(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    """The same command through the dispatcher ``edge_monitor.cli.main``, in this process."""
    code = cli.main(["glr", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture()
def files(tmp_path: Path) -> dict[str, Path]:
    rng = np.random.default_rng(0)
    return {
        "nominal": write_csv(tmp_path / "nominal.csv", "wear", rng.gamma(2.0, size=(300, 1))),
        # a shift of 2 nominal σ over 50 rows: predicted miss probability < 1e-10
        "shifted": write_csv(tmp_path / "shifted.csv", "wear", rng.gamma(2.0, size=(50, 1)) + 2 * np.sqrt(2)),
        # nominal test data: with Pf = 0.01 this fixed-seed draw is quiet (a false alarm has probability ≈ 1 %)
        "same": write_csv(tmp_path / "same.csv", "wear", rng.gamma(2.0, size=(50, 1))),
        "nominal2": write_csv(tmp_path / "nominal2.csv", "kl_raw,kl_weighted", rng.normal(size=(200, 2))),
        "test2": write_csv(tmp_path / "test2.csv", "kl_raw,kl_weighted", rng.normal(size=(60, 2))),
    }


def test_json_output_has_the_system_fields_and_alarms_on_a_shift(files: dict[str, Path]) -> None:
    proc = run_cli("--nominal", str(files["nominal"]), "--test", str(files["shifted"]), "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert SYSTEM_FIELDS <= set(out) and "change_index" not in out
    assert out["alarm"] is True
    assert out["threshold"] == pytest.approx(3.317, abs=1e-3)
    assert out["delta"][0] == pytest.approx(2 * np.sqrt(2), abs=0.8)
    assert out["miss_probability"] < 1e-6
    assert 1 <= out["components"] <= 45            # GCE keeps ≤ 15 % of the 300 nominal rows


@pytest.mark.parametrize("density", ["gauss", "kde", "gce"])
def test_quiet_on_nominal_data_for_every_density(files: dict[str, Path], density: str,
                                                capsys: pytest.CaptureFixture) -> None:
    code, stdout, stderr = run_in_process(capsys, "--nominal", str(files["nominal"]), "--test", str(files["same"]),
                                          "--density", density, "--json")
    assert code == 0, stderr
    out = json.loads(stdout)
    assert out["alarm"] is False
    assert out["miss_probability"] > 0.5


def test_unknown_change_time_reports_the_change_index(tmp_path: Path, files: dict[str, Path],
                                                     capsys: pytest.CaptureFixture) -> None:
    rng = np.random.default_rng(1)
    rows = rng.gamma(2.0, size=(80, 1))
    rows[50:] += 3.0
    test = write_csv(tmp_path / "late.csv", "wear", rows)
    code, stdout, _ = run_in_process(capsys, "--nominal", str(files["nominal"]), "--test", str(test),
                                     "--change-time", "unknown", "--json")
    out = json.loads(stdout)
    assert out["alarm"] is True and abs(out["change_index"] - 50) <= 5


def test_two_dimensional_data_and_the_human_readable_output(files: dict[str, Path]) -> None:
    proc = run_cli("--nominal", str(files["nominal2"]), "--test", str(files["test2"]), "--density", "kde")
    assert proc.returncode == 0, proc.stderr
    assert "no change detected" in proc.stdout and "kl_raw" in proc.stdout


def test_bootstrap_threshold_option(files: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    code, stdout, _ = run_in_process(capsys, "--nominal", str(files["nominal"]), "--test", str(files["same"]),
                                     "--density", "gauss", "--threshold", "bootstrap", "--json")
    out = json.loads(stdout)
    assert code == 0
    assert out["threshold_method"] == "bootstrap" and out["threshold"] > 0


@pytest.mark.parametrize("content, message", [
    ("wear\n1\n2\nabc\n4\n", "row 4, column 'wear'"),
    ("wear\n1\n2\nnan\n4\n", "row 4, column 'wear'"),
    ("wear\n", "no data rows"),
    ("", "empty file"),
    ("a,b\n1,2\n3\n", "row 3 has 1 cells"),
])
def test_bad_csv_names_row_and_column(tmp_path: Path, files: dict[str, Path], content: str, message: str,
                                      capsys: pytest.CaptureFixture) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    code, stdout, stderr = run_in_process(capsys, "--nominal", str(files["nominal"]), "--test", str(bad), "--json")
    assert code == 2 and message in stderr and stdout == ""


def test_bad_input_exit_code_from_the_console_script(tmp_path: Path, files: dict[str, Path]) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("wear\n1\n2\nabc\n")
    proc = run_cli("--nominal", str(files["nominal"]), "--test", str(bad), "--json")
    assert proc.returncode == 2 and "row 4, column 'wear'" in proc.stderr and proc.stdout == ""


def test_bad_input_gives_clear_errors_and_nonzero_exit(tmp_path: Path, files: dict[str, Path],
                                                       capsys: pytest.CaptureFixture) -> None:
    few = write_csv(tmp_path / "few.csv", "wear", np.arange(4.0)[:, None])
    two = write_csv(tmp_path / "two.csv", "wear", np.arange(2.0)[:, None])
    const = write_csv(tmp_path / "const.csv", "wear", np.full((30, 1), 2.0))
    cases = [
        (["--nominal", str(few), "--test", str(files["same"])], "provide at least 10"),
        (["--nominal", str(two), "--test", str(files["same"]), "--density", "gauss"], "provide at least 3"),
        (["--nominal", str(const), "--test", str(files["same"])], "nominal column(s) ['wear'] are constant"),
        (["--nominal", str(files["nominal"]), "--test", str(files["test2"])], "dimension mismatch"),
        (["--nominal", str(files["nominal"]), "--test", str(files["same"]), "--pf", "1.5"], "between 0 and 1"),
        (["--nominal", str(files["nominal"]), "--test", str(files["same"]), "--pf", "0"], "between 0 and 1"),
        (["--nominal", str(tmp_path / "missing.csv"), "--test", str(files["same"])], "cannot read"),
    ]
    for argv, message in cases:  # in-process, through the dispatcher
        assert cli.main(["glr", *argv, "--json"]) == 2
        err = capsys.readouterr().err
        assert message in err, (argv, err)
