"""The same simulated robot through five controller kinds: our frames, CiA 402 drives, a foreign DBC without
cycle, segment or temperature signals, and our recording as a CSV and as a Parquet trace table
(docs/CONNECTING.md). Records each with ``sim-controller record --profile`` (a trace: our frames, written out
with ``edge-monitor export-trace``), replays it with ``edge-monitor replay [--mapping]`` and prints a Markdown
table: alarms
(joint, cycle, quantity), detection delay after the wear ramp starts, and the worn and a healthy joint's
wear estimate ± its reported std at a few cycles, beside the true wear.

    nice -n 10 python tools/studies/connecting_comparison.py --out out/connecting --cycles 200 --joints 6 \
        --wear-ramp 2:100:200:0:40 --seed 3

``--profiles native`` runs some of them (each keeps its own files in ``--out``, so several invocations
may run side by side, one per core); the table lists every profile found there.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
PROFILES = {"native": ("native", None),
            "cia402": ("cia402", ROOT / "protocol/mappings/cia402.toml"),
            "foreign DBC": (f"dbc:{ROOT / 'protocol/mappings/foreign_robot.toml'}",
                            ROOT / "protocol/mappings/foreign_robot.toml"),
            "CSV trace": ("trace:csv", None),
            "Parquet trace": ("trace:parquet", None)}


def run_profile(name: str, profile: str, mapping: Path | None, args: argparse.Namespace) -> dict:
    out = Path(args.out)
    stem = name.replace(" ", "_")
    log, truth, jsonl = out / f"{stem}.blf", out / f"{stem}.truth.jsonl", out / f"{stem}.symptoms.jsonl"
    t0 = time.perf_counter()
    subprocess.run([str(BIN / "sim-controller"), "record", "--out", str(log), "--joints", str(args.joints),
                    "--cycles", str(args.cycles), "--seed", str(args.seed), "--wear-ramp", args.wear_ramp,
                    "--truth", str(truth), "--profile", "native" if profile.startswith("trace:") else profile, "-q"],
                   check=True)
    replayed = log
    if profile.startswith("trace:"):          # our recording as a trace table, replayed with the mapping written beside it
        replayed = out / f"{stem}.{profile.split(':', 1)[1]}"
        mapping = replayed.with_suffix(".toml")
        subprocess.run([str(BIN / "edge-monitor"), "export-trace", str(log), "--out", str(replayed), "--force", "-q"],
                       check=True)
    t1 = time.perf_counter()
    jsonl.unlink(missing_ok=True)
    cmd = [str(BIN / "edge-monitor"), "replay", str(replayed), "--json", "--jsonl", str(jsonl), "-q"]
    if mapping is not None:
        cmd += ["--mapping", str(mapping)]
    stats = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
    t2 = time.perf_counter()
    if not args.keep:
        log.unlink()
        if replayed != log:
            replayed.unlink()
    return {"stats": stats, "symptoms": [json.loads(line) for line in jsonl.open()],
            "truth": [json.loads(line) for line in truth.open() if '"joint"' in line],
            "record_s": t1 - t0, "replay_s": t2 - t1}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/connecting")
    p.add_argument("--cycles", type=int, default=200)
    p.add_argument("--joints", type=int, default=6)
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--wear-ramp", default="2:100:200:0:40")
    p.add_argument("--at", default="99,150,199", help="cycles at which wear estimates are listed")
    p.add_argument("--keep", action="store_true", help="keep the .blf recordings")
    p.add_argument("--report-only", action="store_true", help="only print the table from the files in --out")
    p.add_argument("--profiles", default=",".join(PROFILES),
                   help=f"comma-separated profiles to run (default: all of {', '.join(PROFILES)})")
    args = p.parse_args()
    chosen = [name.strip() for name in args.profiles.split(",") if name.strip()]
    unknown = [name for name in chosen if name not in PROFILES]
    if unknown:
        p.error(f"--profiles: unknown {', '.join(unknown)}; choose from {', '.join(PROFILES)}")
    Path(args.out).mkdir(parents=True, exist_ok=True)
    worn, start = int(args.wear_ramp.split(":")[0]), int(args.wear_ramp.split(":")[1])
    healthy = 0 if worn != 0 else 1
    if not args.report_only:
        for name in chosen:
            profile, mapping = PROFILES[name]
            print(f"{name}: recording and replaying {args.cycles} cycles …", file=sys.stderr, flush=True)
            r = run_profile(name, profile, mapping, args)
            print(f"{name}: recorded in {r['record_s']:.0f} s, replayed in {r['replay_s']:.0f} s",
                  file=sys.stderr, flush=True)
            _stats_file(Path(args.out), name).write_text(json.dumps(
                {"stats": r["stats"], "record_s": r["record_s"], "replay_s": r["replay_s"]}))
    results = _from_files(Path(args.out))
    print("| | " + " | ".join(results) + " |")
    print("|---|" + "---|" * len(results))
    row = {name: r for name, r in results.items()}

    def line(label: str, fn) -> None:
        print(f"| {label} | " + " | ".join(fn(r) for r in row.values()) + " |")

    def alarms(r: dict) -> str:
        a = r["stats"]["alarms"]
        return ", ".join(f"j{x['joint']} c{x['cycle']} {x['quantity']}" for x in a) or "none"

    def first_alarm(r: dict, joint: int) -> str:
        cycles = [x["cycle"] for x in r["stats"]["alarms"] if x["joint"] == joint]
        return f"{min(cycles) - start} cycles (cycle {min(cycles)})" if cycles else "no alarm"

    def wear(r: dict, joint: int, cycle: int) -> str:
        s = next((x for x in r["symptoms"] if x["joint"] == joint and x["cycle"] == cycle), None)
        true = next((t["wear"] for t in r["truth"] if t["joint"] == joint and t["cycle"] == cycle), float("nan"))
        if s is None or not s.get("wear") or s["wear"].get("estimate") is None:
            return f"– (true {true:.1f})"
        return f"{s['wear']['estimate']:.1f} ± {s['wear']['std']:.1f} (true {true:.1f})"

    line("cycles / symptoms", lambda r: f"{r['stats']['cycles']} / {r['stats']['symptoms']}")
    line("first alarm per (joint, quantity): joint cycle quantity", alarms)
    line(f"detection delay, joint {worn}", lambda r: first_alarm(r, worn))
    for c in [int(v) for v in args.at.split(",")]:
        line(f"wear joint {worn}, cycle {c}", lambda r: wear(r, worn, c))
        line(f"wear joint {healthy}, cycle {c}", lambda r: wear(r, healthy, c))
    line(f"healthy joints: mean reported wear std, cycles {start}–{args.cycles - 1}",
         lambda r: f"{_mean_std(r, worn, start):.2f}")
    line(f"healthy joints: RMS wear error, cycles {start}–{args.cycles - 1}",
         lambda r: f"{_rms_error(r, worn, start):.2f}")
    line("frames (a trace: none, rows)", lambda r: f"{r['stats']['frames_total']:,}" if r["stats"].get("frames_total")
         else "–")
    return 0


def _from_files(out: Path) -> dict:
    """Each profile's symptoms and truth in ``out`` (profiles not run yet are left out); alarms: the first
    cycle each (joint, quantity) decision reads alarm."""
    results = {}
    for name in PROFILES:
        stem = name.replace(" ", "_")
        if not (out / f"{stem}.symptoms.jsonl").exists() or not (out / f"{stem}.truth.jsonl").exists():
            continue
        records = [json.loads(line) for line in (out / f"{stem}.symptoms.jsonl").open()]
        symptoms = [r for r in records if "kind" not in r]       # alarm and advisory records are apart
        first: dict[tuple[int, str], int] = {}
        for s in symptoms:
            for q, d in s["decisions"].items():
                if d.get("alarm"):
                    first.setdefault((s["joint"], q), s["cycle"])
        saved, legacy = _stats_file(out, name), out / "results.json"       # (all profiles' stats, before --profiles)
        stats = json.loads(saved.read_text()).get("stats", {}) if saved.exists() else \
            json.loads(legacy.read_text()).get(name, {}).get("stats", {}) if legacy.exists() else {}
        stats["alarms"] = [{"joint": j, "cycle": c, "quantity": q} for (j, q), c in sorted(first.items(),
                                                                                          key=lambda x: x[1])]
        stats.setdefault("cycles", max((s["cycle"] for s in symptoms), default=-1) + 1)
        stats.setdefault("symptoms", len(symptoms))
        results[name] = {"stats": stats, "symptoms": symptoms,
                         "truth": [json.loads(line) for line in (out / f"{stem}.truth.jsonl").open()
                                   if '"joint"' in line]}
    return results


def _stats_file(out: Path, name: str) -> Path:
    return out / f"{name.replace(' ', '_')}.stats.json"


def _healthy(r: dict, worn: int, start: int) -> list[tuple[dict, float]]:
    truth = {(t["joint"], t["cycle"]): t["wear"] for t in r["truth"]}
    return [(s["wear"], truth[(s["joint"], s["cycle"])]) for s in r["symptoms"]
            if s["joint"] != worn and s["cycle"] >= start and (s.get("wear") or {}).get("estimate") is not None]


def _mean_std(r: dict, worn: int, start: int) -> float:
    values = [w["std"] for w, _ in _healthy(r, worn, start) if w.get("std") is not None]
    return sum(values) / max(len(values), 1)


def _rms_error(r: dict, worn: int, start: int) -> float:
    errors = [(w["estimate"] - true) ** 2 for w, true in _healthy(r, worn, start)]
    return (sum(errors) / max(len(errors), 1)) ** 0.5


if __name__ == "__main__":
    raise SystemExit(main())
