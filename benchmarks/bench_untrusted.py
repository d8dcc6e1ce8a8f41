"""Untrusted files and interrupted runs (issue 16): a seeded fuzz campaign over every reader, code-
execution probes, kill -9 during every multi-file writer, and peak memory of "bomb" inputs; the
untrusted-recording campaign (issue 31): mutated bags of all three containers, CameraInfo YAML /
intrinsics JSON files and mmdetection3d info pickles (``tests/_bag_cases.py``), and FIFOs /
``/dev/zero`` symlinks in the place of each bag.

    PYTHONPATH=src python benchmarks/bench_untrusted.py [--cases 200] [--kills 8] [--bag-cases 220]
    PYTHONPATH=src python benchmarks/bench_untrusted.py --part recordings   # only the bag campaign

Every reader case runs in a worker process (restarted after a case that hangs for more than
``--timeout`` s, counted as unclear). Prints one table per part and writes
``benchmarks/results/untrusted.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import random
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
RESULTS = REPO / "benchmarks" / "results" / "untrusted.json"
PY = sys.executable
ENV = dict(os.environ, PYTHONPATH=str(REPO / "src"), OMP_NUM_THREADS="1")


# ----------------------------------------------------------------------------- fuzz worker
_WORKER = r'''
import logging, os, sys, warnings
sys.path.insert(0, "tests")
logging.disable(logging.CRITICAL)
warnings.simplefilter("ignore")
out = os.fdopen(os.dup(1), "w")
os.dup2(os.open(os.devnull, os.O_WRONLY), 1)  # libpng / libjpeg / h5py chatter
os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
from _untrusted_cases import Samples, run_case
samples = Samples(sys.argv[1])
for line in sys.stdin:
    name, kind, a, b = line.split()
    outcome, detail = run_case(samples, name, kind, int(a), int(b))
    out.write(outcome + "\t" + detail.replace("\n", " ").replace("\t", " ") + "\n")
    out.flush()
'''


class Pool:
    """One worker process fed over stdin; a case that does not answer within ``timeout`` s (a hang
    or a crash) kills and restarts it and counts as unclear."""

    def __init__(self, root: str, timeout: float):
        self.root, self.timeout = root, timeout
        self._start()

    def _start(self) -> None:
        self.proc = subprocess.Popen([PY, "-c", _WORKER, self.root], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, text=True, env=ENV, cwd=REPO, bufsize=1)

    def run(self, task) -> tuple[str, str]:
        import select

        try:
            self.proc.stdin.write(" ".join(map(str, task)) + "\n")
            self.proc.stdin.flush()
            ready, _, _ = select.select([self.proc.stdout], [], [], self.timeout)
            line = self.proc.stdout.readline() if ready else ""
        except (BrokenPipeError, OSError):
            line = ""
        if line:
            outcome, _, detail = line.rstrip("\n").partition("\t")
            return outcome, detail
        self.proc.kill()
        self.proc.wait()
        self._start()
        return "unclear", f"no answer within {self.timeout:.0f} s (hang or crash)"

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=30)


def fuzz(cases: int, timeout: float, names=None) -> dict:
    """``cases`` seeded mutations per reader (``names``: a subset of the readers; the seeds do not
    depend on it) -> outcome counts per reader, and ``outcomes``: one letter per case in order
    (o ok, c clear, u unclear, g garbage). The first n cases of a run are those of a run with
    ``cases=n`` (each reader's seeds are drawn in order), so a prefix can be re-checked."""
    from _untrusted_cases import KINDS, READERS

    out = {}
    with tempfile.TemporaryDirectory() as root:
        pool = Pool(root, timeout)
        for name in READERS if names is None else names:
            rnd = random.Random(f"bench-{name}")
            c: Counter = Counter()
            letters: list[str] = []
            examples: list[str] = []
            t0 = time.perf_counter()
            for i in range(cases):
                kind = KINDS[i % len(KINDS)]
                outcome, detail = pool.run((name, kind, rnd.randrange(1 << 30), rnd.randrange(1 << 30)))
                c[outcome] += 1
                letters.append(outcome[0])
                if outcome in ("unclear", "garbage") and len(examples) < 3:
                    examples.append(f"{kind}: {detail}")
            out[name] = {"tried": cases, "ok": c["ok"], "clear": c["clear"], "unclear": c["unclear"],
                         "garbage": c["garbage"], "seconds": round(time.perf_counter() - t0, 2), "examples": examples,
                         "outcomes": "".join(letters)}
            print(f"  {name:22s} {dict(c)}", flush=True)
        pool.close()
    return out


# ---------------------------------------------------------------------------- special files
_SPECIAL = r'''
import os, sys, signal
sys.path.insert(0, "tests")
from _untrusted_cases import READERS, classify
from pathlib import Path
name, path = sys.argv[1], Path(sys.argv[2])
print(classify(READERS[name], path)[0])
'''


def special_files(timeout: float) -> dict:
    """A FIFO and a symlink to /dev/zero in the place of each reader's file."""
    from _untrusted_cases import READERS, Samples

    rows = {}
    with tempfile.TemporaryDirectory() as root:
        s = Samples(root)
        for name in READERS:
            try:
                d, f = s.base(name)
            except FileNotFoundError:
                continue
            res = {}
            for kind in ("fifo", "dev_zero"):
                case = Path(root) / f"special_{name}_{kind}"
                import shutil

                shutil.copytree(d, case, symlinks=True)
                target = case / f.relative_to(d)
                target.unlink()
                os.mkfifo(target) if kind == "fifo" else target.symlink_to("/dev/zero")
                try:
                    r = subprocess.run([PY, "-c", _SPECIAL, name, str(target)], capture_output=True, text=True,
                                       timeout=timeout, env=ENV, cwd=REPO)
                    res[kind] = (r.stdout.strip().splitlines() or ["crash"])[-1]
                except subprocess.TimeoutExpired:
                    res[kind] = "hang"
            rows[name] = res
    return rows


# ------------------------------------------------------------------------- code execution
_EXEC = r'''
import os, sys, pickle, io
sys.path.insert(0, "tests")
marker, kind, path = sys.argv[1], sys.argv[2], sys.argv[3]
from xcalib.errors import FormatError
try:
    if kind == "resume":
        from xcalib.engine.checkpoint import load_resume_state; load_resume_state(path)
    elif kind == "weights":
        from xcalib.engine.checkpoint import read_checkpoint; read_checkpoint(path)
    elif kind == "mmdet3d_pkl":
        from xcalib.formats.mmdet3d import read_mmdet3d_infos; read_mmdet3d_infos(path)
    elif kind == "npy":
        from xcalib.io import read_point_cloud; read_point_cloud(path)
    elif kind == "npz":
        from xcalib.calib.result import CalibrationResult; CalibrationResult.load(path)
    elif kind == "train_resume":
        from pathlib import Path
        from xcalib.data.synth import iter_frames, sample_site
        from xcalib.engine.trainer import train
        train("fastmatch", list(iter_frames(sample_site(0), 2, seed=1, render_images=False)), epochs=1,
              output_dir=Path(path).parent, resume=True, progress=False, device="cpu")
    print("loaded")
except FormatError:
    print("refused")
except Exception as e:
    print("error", type(e).__name__)
'''


class _Boom:
    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def code_execution(timeout: float) -> dict:
    import numpy as np

    rows = {}
    with tempfile.TemporaryDirectory() as root:
        root = Path(root)
        for kind in ("resume", "train_resume", "weights", "mmdet3d_pkl", "npy", "npz"):
            marker = root / f"PWNED_{kind}"
            boom = _Boom(str(marker))
            d = root / kind
            d.mkdir()
            if kind in ("resume", "train_resume", "weights"):
                import torch

                p = d / ("last.pt" if "resume" in kind else "fastmatch.pt")
                torch.save({"state_dict": {}, "optimizer": boom, "epoch": 0, "best_mrr": 0.0}, p)
            elif kind == "mmdet3d_pkl":
                p = d / "infos.pkl"
                p.write_bytes(pickle.dumps({"data_list": [boom], "metainfo": {}}))
            elif kind == "npy":
                p = d / "cloud.npy"
                np.save(p, np.array([boom, 1], dtype=object), allow_pickle=True)
            else:
                p = d / "calibration.npz"
                np.savez(p, json=np.array([boom], dtype=object), rotation=np.eye(3))
            try:
                r = subprocess.run([PY, "-c", _EXEC, str(marker), kind, str(p)], capture_output=True, text=True,
                                   timeout=timeout * 6, env=ENV, cwd=REPO)
                got = (r.stdout.strip().splitlines() or ["crash"])[-1]
            except subprocess.TimeoutExpired:
                got = "hang"
            rows[kind] = {"outcome": got, "code_ran": marker.exists()}
    return rows


# --------------------------------------------------------------------------------- kill -9
def kills(n: int) -> dict:
    from _kill_writers import KINDS, check, kill_during_write, leftovers, sweep

    rows = {}
    for kind in KINDS:
        rnd = random.Random(f"kill-{kind}")
        mixed = left = 0
        details = []
        for _ in range(n):
            with tempfile.TemporaryDirectory() as t:
                out = Path(t) / "out"
                kill_during_write(kind, out, rnd.uniform(0.02, 0.5))
                whole, detail = check(kind, out)
                before = len(leftovers(out))
                sweep(out)
                after = leftovers(out)
                mixed += not whole
                left += len(after)
                if not whole:
                    details.append(detail)
        rows[kind] = {"kills": n, "half_written_or_mixed": mixed, "leftover_temp_after_sweep": left,
                      "temp_before_sweep_last": before, "details": details[:3]}
        print(f"  {kind:18s} kills {n}: mixed {mixed}, leftover temps {left}", flush=True)
    return rows


# ----------------------------------------------------------------------------------- bombs
_BOMB = r'''
import sys
sys.path.insert(0, "tests")
from _untrusted_cases import READERS, classify
from pathlib import Path
import xcalib.io, xcalib.io.hdf5, xcalib.calib.result, cv2  # baseline imports


def hwm_kb():  # peak RSS of this process image (ru_maxrss would include the parent's before exec)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1])


base = hwm_kb()
name, path = sys.argv[1], Path(sys.argv[2])
out = classify(READERS[name], path) if name != "baseline" else ("ok", "")
print(out[0], base, hwm_kb(), out[1][:150].replace(chr(10), " "))
'''


def _png_bomb(p: Path, side: int = 20000) -> None:
    def chunk(t: bytes, d: bytes) -> bytes:
        return len(d).to_bytes(4, "big") + t + d + zlib.crc32(t + d).to_bytes(4, "big")

    comp = zlib.compressobj(9)
    row = b"\x00" * (1 + 3 * side)
    idat = b"".join(comp.compress(row) for _ in range(side)) + comp.flush()
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", side.to_bytes(4, "big") * 2 + b"\x08\x02\x00\x00\x00")
                  + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def _npz_bomb(p: Path, gb: float = 2.0) -> None:
    import numpy as np

    n = int(gb * (1 << 30))
    with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("rotation.npy", "w", force_zip64=True) as f:
            hdr = np.lib.format.header_data_from_array_1_0(np.zeros(1))
            hdr["shape"] = (n // 8,)
            np.lib.format.write_array_header_1_0(f, hdr)
            block = b"\x00" * (1 << 24)
            for _ in range(n // len(block)):
                f.write(block)
        z.writestr("json.npy", b"")


def _h5_bomb(p: Path) -> None:
    import h5py
    import numpy as np

    with h5py.File(p, "w") as f:
        f.create_dataset("images/cam/data", shape=(1,), dtype=h5py.vlen_dtype(np.uint8))
        g = f.create_group("labels/cam/000000")
        g["num_camera_detections"], g["num_lidar_detections"] = 0, 0
        g["camera_bbox_2d"], g["lidar_bbox_3d"] = np.zeros((0, 4), np.float32), np.zeros((0, 6), np.float32)
        f.create_dataset("point_clouds/lidar/000000/xyz", shape=(100_000_000, 3), dtype=np.float32,
                         chunks=(1_000_000, 3), compression="gzip")


def bombs() -> dict:
    specs = {
        "baseline (imports only)": ("baseline", None),
        "HDF5 declaring 1e8 points": ("hdf5_cache", _h5_bomb),
        "PCD COUNT 1000000000": ("pcd_binary", lambda p: p.write_bytes(
            b"VERSION 0.7\nFIELDS x y z i\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1000000000\nWIDTH 1\nHEIGHT 1\n"
            b"POINTS 1\nDATA binary\n" + b"\x00" * 64)),
        "PCD POINTS 1e9 (ascii)": ("pcd_ascii", lambda p: p.write_bytes(
            b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1000000000\nHEIGHT 1\n"
            b"POINTS 1000000000\nDATA ascii\n1 2 3\n")),
        "npz inflating to 2 GB": ("calibration_npz", _npz_bomb),
        "PNG 20000x20000": ("png", _png_bomb),
        "JSON nested 1e6 deep": ("calibration_json", lambda p: p.write_bytes(b"[" * 1_000_000)),
        ".npy declaring 1e10 floats": ("npy", lambda p: p.write_bytes(
            b"\x93NUMPY\x01\x00v\x00{'descr': '<f4', 'fortran_order': False, 'shape': (10000000000, 4), }"
            + b" " * 43 + b"\n")),
    }
    names = {"hdf5_cache": "cache.h5", "pcd_binary": "cloud.pcd", "pcd_ascii": "cloud.pcd",
             "calibration_npz": "calibration.npz", "png": "img.png", "calibration_json": "calibration.json",
             "npy": "cloud.npy", "baseline": "x"}
    rows = {}
    with tempfile.TemporaryDirectory() as t:
        for label, (reader, make) in specs.items():
            p = Path(t) / label.replace(" ", "_") / names[reader]
            p.parent.mkdir()
            if make is not None:
                make(p)
            r = subprocess.run([PY, "-c", _BOMB, reader, str(p)], capture_output=True, text=True, timeout=300,
                               env=ENV, cwd=REPO)
            parts = (r.stdout.strip().splitlines() or ["crash 0 0"])[-1].split(" ", 3)
            size = p.stat().st_size if p.exists() else 0
            rows[label] = {"file_bytes": size, "outcome": parts[0], "baseline_rss_mb": round(int(parts[1]) / 1024, 1),
                           "peak_rss_mb": round(int(parts[2]) / 1024, 1),
                           "detail": parts[3] if len(parts) > 3 else r.stderr[-200:]}
            print(f"  {label:28s} {rows[label]['outcome']:8s} peak {rows[label]['peak_rss_mb']:7.1f} MB", flush=True)
    return rows


# ------------------------------------------------------------------------------ recordings
def recordings(bag_cases: int, file_cases: int, timeout: float, max_rss_mb: float) -> dict:
    """The issue-31 campaign: ``bag_cases`` mutated bags per container, ``file_cases`` mutated
    CameraInfo YAML / intrinsics JSON / mmdet3d pickles, each read in a killable worker (a case
    without an answer in ``timeout`` s is a hang, a worker past ``max_rss_mb`` a memory blow-up);
    then a FIFO and a symlink to /dev/zero named like each container."""
    from _bag_cases import OUTCOMES, READERS, Pool, plan

    out: dict = {"readers": {}, "special_files": {}}
    with tempfile.TemporaryDirectory() as root:
        pool = Pool(root, REPO / "tests", ENV, timeout=timeout, max_rss_mb=max_rss_mb)
        for reader in READERS:
            n = bag_cases if reader in ("bag", "db3", "mcap") else file_cases
            c: Counter = Counter()
            by_kind: dict[str, Counter] = {}
            examples: list[str] = []
            peak = 0.0
            t0 = time.perf_counter()
            for case in plan(reader, n, "bench"):
                outcome, detail, rss = pool.run(case)
                peak = max(peak, rss)
                c[outcome] += 1
                by_kind.setdefault(case[1], Counter())[outcome] += 1
                if outcome not in ("ok", "clear") and len(examples) < 8:
                    examples.append(f"{case[1]} a={case[2]} b={case[3]}: {outcome}: {detail[:200]}")
            out["readers"][reader] = {"tried": n, **{k: c[k] for k in OUTCOMES}, "worker_peak_rss_mb": round(peak, 1),
                                      "seconds": round(time.perf_counter() - t0, 1), "examples": examples,
                                      "by_kind": {k: dict(v) for k, v in sorted(by_kind.items())}}
            print(f"  {reader:18s} {dict(c)}", flush=True)
        pool.close()
        for suffix in (".bag", ".db3", ".mcap"):
            res = {}
            for kind in ("fifo", "dev_zero"):
                target = Path(root) / f"special_{kind}{suffix}"
                os.mkfifo(target) if kind == "fifo" else target.symlink_to("/dev/zero")
                code = ("import sys; sys.path.insert(0, 'tests'); from pathlib import Path; "
                        "from _bag_cases import classify_bag; print(classify_bag(Path(sys.argv[1]), None)[0])")
                try:
                    r = subprocess.run([PY, "-c", code, str(target)], capture_output=True, text=True, timeout=timeout,
                                       env=ENV, cwd=REPO)
                    res[kind] = (r.stdout.strip().splitlines() or ["crash"])[-1]
                except subprocess.TimeoutExpired:
                    res[kind] = "hang"
            out["special_files"][suffix] = res
            print(f"  special {suffix:5s} {res}", flush=True)
    tot = Counter()
    for r in out["readers"].values():
        tot.update({k: r[k] for k in ("tried", *OUTCOMES)})
    bags = Counter()
    for k in ("bag", "db3", "mcap"):
        bags.update({o: out["readers"][k][o] for o in ("tried", *OUTCOMES)})
    out["summary"] = {
        "bag_inputs": bags["tried"], **{f"bag_{o}": bags[o] for o in OUTCOMES},
        "file_inputs": tot["tried"] - bags["tried"], **{f"file_{o}": tot[o] - bags[o] for o in OUTCOMES},
        "special_file_cases": sum(len(v) for v in out["special_files"].values()),
        "special_file_not_clear": sum(v != "clear" for r in out["special_files"].values() for v in r.values()),
        "max_worker_peak_rss_mb": max(r["worker_peak_rss_mb"] for r in out["readers"].values())}
    return out


def _print_recordings(rec: dict) -> None:
    from _bag_cases import OUTCOMES

    print(f"\n{'recording reader':18s} {'tried':>6s} " + " ".join(f"{o:>8s}" for o in OUTCOMES) + "  peak MB")
    for name, r in rec["readers"].items():
        print(f"{name:18s} {r['tried']:6d} " + " ".join(f"{r[o]:8d}" for o in OUTCOMES)
              + f"  {r['worker_peak_rss_mb']:7.0f}")
    print("special files: " + ", ".join(f"{k} {v}" for k, v in rec["special_files"].items()))
    print("recordings summary: " + json.dumps(rec["summary"]))


# ------------------------------------------------------------------------------------ main
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=200, help="mutated inputs per reader")
    ap.add_argument("--kills", type=int, default=8, help="kill -9 runs per multi-file output")
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds before a case counts as a hang")
    ap.add_argument("--bag-cases", type=int, default=220, help="mutated bags per container (issue 31)")
    ap.add_argument("--file-cases", type=int, default=200,
                    help="mutated CameraInfo YAML / intrinsics JSON / mmdet3d pickles each (issue 31)")
    ap.add_argument("--max-rss-mb", type=float, default=1500.0, help="worker peak RSS counted as a memory blow-up")
    ap.add_argument("--part", choices=("all", "readers", "recordings"), default="all",
                    help="readers: the issue-16 parts; recordings: the issue-31 campaign (the other part's "
                         "results in the JSON are kept)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    old = json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}
    doc = dict(old)
    if args.part in ("all", "readers"):
        doc.update(_readers_part(args))
    if args.part in ("all", "recordings"):
        print("untrusted recordings (issue 31)", flush=True)
        rec = recordings(args.bag_cases, args.file_cases, max(args.timeout, 30.0), args.max_rss_mb)
        _print_recordings(rec)
        doc["recordings"] = {"command": "PYTHONPATH=src python benchmarks/bench_untrusted.py --part recordings "
                                        f"--bag-cases {args.bag_cases} --file-cases {args.file_cases}"
                                        + (f" --timeout {args.timeout:g}" if args.timeout != 20.0 else ""),
                             "wall_s": round(time.perf_counter() - t0, 1), **rec}
    doc.setdefault("benchmark", "untrusted")
    doc["machine"] = {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()}
    from _provenance import provenance

    if "provenance_recordings" not in doc and "--part recordings" in str(old.get("provenance", {}).get("command")):
        doc["provenance_recordings"] = old["provenance"]  # files written before the per-part stamps
    doc["provenance"] = provenance()
    for part in ("readers", "recordings"):
        if args.part in ("all", part):
            doc[f"provenance_{part}"] = doc["provenance"]
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {RESULTS.relative_to(REPO)}")


def _readers_part(args) -> dict:
    t0 = time.perf_counter()
    print("fuzz campaign", flush=True)
    fz = fuzz(args.cases, args.timeout)
    print("special files (FIFO, symlink to /dev/zero)", flush=True)
    sp = special_files(args.timeout)
    print("code execution probes", flush=True)
    ce = code_execution(args.timeout)
    print("kill -9 during writes", flush=True)
    kl = kills(args.kills)
    print("bomb inputs", flush=True)
    bm = bombs()

    print(f"\n{'reader':22s} {'tried':>6s} {'ok':>5s} {'clear':>6s} {'unclear':>8s} {'garbage':>8s}  FIFO / ->/dev/zero")
    tot = Counter()
    for name, r in fz.items():
        s = sp.get(name, {})
        print(f"{name:22s} {r['tried']:6d} {r['ok']:5d} {r['clear']:6d} {r['unclear']:8d} {r['garbage']:8d}  "
              f"{s.get('fifo', '-')} / {s.get('dev_zero', '-')}")
        tot.update({k: r[k] for k in ("tried", "ok", "clear", "unclear", "garbage")})
    print(f"{'TOTAL':22s} {tot['tried']:6d} {tot['ok']:5d} {tot['clear']:6d} {tot['unclear']:8d} {tot['garbage']:8d}")
    print(f"\ncode execution: {sum(r['code_ran'] for r in ce.values())} of {len(ce)} probes ran code; "
          + ", ".join(f"{k}: {v['outcome']}" for k, v in ce.items()))
    print(f"\n{'multi-file output':20s} {'kills':>5s} {'mixed':>6s} {'leftover temps':>15s}")
    for k, r in kl.items():
        print(f"{k:20s} {r['kills']:5d} {r['half_written_or_mixed']:6d} {r['leftover_temp_after_sweep']:15d}")
    print(f"\n{'bomb input':30s} {'file':>10s} {'outcome':>8s} {'peak RSS MB':>12s}")
    for k, r in bm.items():
        print(f"{k:30s} {r['file_bytes']:10d} {r['outcome']:>8s} {r['peak_rss_mb']:12.1f}")
    special_bad = sum(v not in ("clear", "ok") for r in sp.values() for v in r.values())  # ok: not read at all
    summary = {"inputs_tried": tot["tried"], "clear_errors": tot["clear"], "ok_valid": tot["ok"],
               "unclear_errors": tot["unclear"], "silent_garbage": tot["garbage"],
               "special_file_cases": sum(len(r) for r in sp.values()), "special_file_not_clear": special_bad,
               "code_execution": sum(r["code_ran"] for r in ce.values()),
               "half_written_or_mixed_after_kill9": sum(r["half_written_or_mixed"] for r in kl.values()),
               "kills": sum(r["kills"] for r in kl.values()),
               "leftover_temp_files": sum(r["leftover_temp_after_sweep"] for r in kl.values()),
               "bomb_peak_rss_mb_max": max(r["peak_rss_mb"] for k, r in bm.items() if not k.startswith("baseline"))}
    print("\nsummary: " + json.dumps(summary))
    return {"command": "PYTHONPATH=src python benchmarks/bench_untrusted.py "
                       f"--cases {args.cases} --kills {args.kills}",
            "wall_s": round(time.perf_counter() - t0, 1), "summary": summary, "fuzz": fz, "special_files": sp,
            "code_execution": ce, "kill9": kl, "bombs": bm}


if __name__ == "__main__":
    main()
