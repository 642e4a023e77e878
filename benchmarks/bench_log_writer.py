#!/usr/bin/env python3
"""What writing a run's ``log.npz`` costs, by codec: numpy's ``savez_compressed`` (zlib level 6),
``savez`` (stored) and a deflate at level 1, on the log of one run of a case of
``bench_peer.py`` (``ten_hz`` or ``default``), next to the run's own process CPU::

    .venv/bin/python benchmarks/bench_log_writer.py                  # ten_hz, 5000 s
    .venv/bin/python benchmarks/bench_log_writer.py --case default --duration 1000

Prints per codec: the file's size, the CPU to write it and to read every array back (``np.load``,
as ``RunLog.load`` does), and the write's share of the run's process CPU (the run's simulate
plus the write). Every archive is checked to read back equal to the log.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import zipfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import bench_peer  # noqa: E402


def _deflate_level_1(path: str, arrays: dict) -> None:
    """``np.savez``'s layout (one ``<name>.npy`` per array) deflated at level 1."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for name, value in arrays.items():
            with z.open(f"{name}.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=False)


def _identical(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


CODECS = {
    "savez_compressed": lambda path, arrays: np.savez_compressed(path, **arrays),
    "savez (stored)": lambda path, arrays: np.savez(path, **arrays),
    "deflate level 1": _deflate_level_1,
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", choices=("ten_hz", "default"), default="ten_hz")
    ap.add_argument("--duration", type=float, default=5000.0)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    if not (args.duration > 0 and args.repeats >= 1):
        ap.error(f"--duration {args.duration:g}, --repeats {args.repeats}: need > 0 and >= 1")
    sd, _ = bench_peer.build_diagram(args.case, args.duration)
    bench_peer.warm_up_drake(args.case, sd, 2)
    t0 = time.process_time()
    run = sd.simulate(seed=1)
    run_cpu = time.process_time() - t0
    arrays = run.to_npz_dict()
    raw = sum(np.asarray(v).nbytes for v in arrays.values())
    print(
        f"{args.case}, {args.duration:g} s: simulate {run_cpu:.2f} s CPU; log {len(arrays)} arrays, {raw / 1e6:.1f} MB"
    )
    print(f"{'codec':<18} {'MB':>7} {'write s':>8} {'read s':>7} {'write / (run + write)':>22}")
    with tempfile.TemporaryDirectory() as folder:
        for name, write in CODECS.items():
            path = os.path.join(folder, "log.npz")
            writes, reads = [], []
            for _ in range(args.repeats):
                t = time.process_time()
                write(path, arrays)
                writes.append(time.process_time() - t)
                t = time.process_time()
                with np.load(path, allow_pickle=False) as npz:
                    back = {k: npz[k] for k in npz.files}
                reads.append(time.process_time() - t)
            same = back.keys() == arrays.keys() and all(_identical(back[k], arrays[k]) for k in arrays)
            assert same, f"{name}: the archive does not read back as the log"
            w = min(writes)
            print(
                f"{name:<18} {os.path.getsize(path) / 1e6:>7.1f} {w:>8.3f} {min(reads):>7.3f} "
                f"{100 * w / (run_cpu + w):>21.1f}%"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
