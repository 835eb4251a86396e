"""Generated malformed inputs across every reader and option, each run in a child process under limits.

    PYTHONPATH=. nice -n 10 python benchmarks/fuzz_inputs.py --examples 2000 [--api 1000] [--seed 0]
        [--timeout 20] [--memory-gb 8] [--family "map file"] [--show 5] [--json counts.json]

Run it under ``ulimit -v 8000000`` to bound the parent too: the children never raise their limit above it.

For each case (``sensor_envs/testing/fuzz_cases.py``: a valid piece, one generated mutation, the command that reads
it and the loader behind it), a forked child process (the package imported once in the parent) with
an address-space limit (``RLIMIT_AS``, ``ulimit -v``) of ``--memory-gb`` and a wall-clock limit of
``--timeout`` seconds runs the loader and then ``sensor-envs`` in-process, and reports its class:

* ``clean error``: exit 2, one line naming the file or option, no traceback, nothing written;
* ``vague message``: exit 2, one line that names neither;
* ``traceback``: the loader or the command raised anything but an input error;
* ``accepted nonsense``: an input that breaks the format taken by the loader or the command;
* ``accepted``: a mutation that may well be valid (a truncation at a line end, a duplicated line...) taken;
* ``hang``: killed at the time limit; ``memory``: ``MemoryError`` or killed under the memory limit;
* ``files changed``: an input changed, or a file left behind by a failed command.

With ``--api N``, N generated Python API calls follow (``sensor_envs/testing/fuzz_api.py``: env constructors of every
registered env id with their keyword arguments and highway-env config keys, ``reset`` and ``step`` with bad
seeds, options and actions, the vector Neato entry, and ``fit`` / constructor / ``sample`` / ``log_prob`` /
``load`` of every model class), each in a forked child under the same limits, counted per call class.
A call must raise ``InputError`` or return a sane result (observations finite and in the observation space,
finite rewards, finite samples or NaN miss rows, log-probabilities that are not NaN); any other exception is
a traceback, a certainly-invalid argument taken is accepted nonsense.

Prints a table of counts per family and class, then the first ``--show`` cases of every bad class.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import random
import resource
import signal
import sys
import tempfile
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sensor_envs.testing.fuzz_api as fa
import sensor_envs.testing.fuzz_cases as fc

BAD = ("traceback", "accepted nonsense", "hang", "memory", "files changed", "vague message", "exit", "harness error")


class Seeded:
    """A chooser over ``random.Random(seed)``."""

    def __init__(self, seed: int) -> None:
        self.r = random.Random(seed)

    def integers(self, lo: int, hi: int) -> int:
        return self.r.randint(lo, hi)

    def choice(self, seq):
        return self.r.choice(list(seq))


def run_one(family: str, seed: int, timeout: float, memory_gb: float, api: bool = False) -> tuple[str, str]:
    """``(class, mutation)`` of one generated case (``api``: a Python API call of class ``family``), forked."""
    with tempfile.TemporaryDirectory(prefix="fuzz.") as tmp:
        d = Path(tmp)
        case = (fa.make_api_case if api else fc.make_case)(family, Seeded(seed), d)
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:  # child
            os.close(r)
            try:
                soft, hard = resource.getrlimit(resource.RLIMIT_AS)  # under `ulimit -v`, never above it
                limit = int(memory_gb * 2**30)
                limit = limit if hard == resource.RLIM_INFINITY else min(limit, hard)
                resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
                warnings.simplefilter("ignore")
                try:
                    kind = fc.classify(case, d)
                except MemoryError:
                    kind = "memory"
                os.write(w, kind.encode())
            except BaseException as exc:  # a harness fault is reported as such, never counted as "memory"
                os.write(w, f"harness error ({type(exc).__name__}: {exc})"[:4000].encode())
            finally:
                os._exit(0)
        os.close(w)
        deadline = time.monotonic() + timeout
        status = None
        while time.monotonic() < deadline:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            time.sleep(0.02)
        else:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            os.close(r)
            return "hang", case.mutation
        out = os.read(r, 4096).decode()
        os.close(r)
        if not out:
            sig = os.WTERMSIG(status) if status is not None and os.WIFSIGNALED(status) else None
            return ("memory" if sig in (signal.SIGKILL, signal.SIGSEGV, None) else f"killed {sig}"), case.mutation
        if "MemoryError" in out:
            out = "memory"
        return out, case.mutation


def main() -> None:
    """Run the cases and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--examples", type=int, default=200, help="generated cases in all (split over the families)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds per case (the issue's bound is 120)")
    ap.add_argument("--memory-gb", type=float, default=8.0)
    ap.add_argument("--family", action="append", default=None, help="only these families (repeatable)")
    ap.add_argument("--show", type=int, default=5, help="bad cases listed per class")
    ap.add_argument("--json", default=None, help="also write the counts to this file")
    ap.add_argument(
        "--api", type=int, default=0, help="also this many generated Python API calls (testing.fuzz_api classes)"
    )
    args = ap.parse_args()
    families = args.family or list(fc.FAMILIES)
    import sensor_envs.cli.main
    import sensor_envs.lidar.lwlr
    import sensor_envs.radar.astyx
    import sensor_envs.radar.kde  # noqa: F401

    t0 = time.perf_counter()
    results = run_part(families, args.examples, args, api=False)
    print(
        f"Files and options: {args.examples} generated cases, seed {args.seed}, {args.timeout:g} s and "
        f"{args.memory_gb:g} GB per case, {time.perf_counter() - t0:.0f} s\n"
    )
    report(*results)
    if args.api:
        fa.warm_up()  # models, envs and highway-env loaded once; every child inherits them
        t0 = time.perf_counter()
        api = run_part(list(fa.API_CLASSES), args.api, args, api=True)
        print(
            f"\nPython API: {args.api} generated calls, seed {args.seed}, {args.timeout:g} s and "
            f"{args.memory_gb:g} GB per call, {time.perf_counter() - t0:.0f} s\n"
        )
        report(*api)
    if args.json:
        out = {"files": {f: dict(c) for f, c in results[0].items()}}
        if args.api:
            out["api"] = {f: dict(c) for f, c in api[0].items()}
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")


def run_part(families: list[str], n: int, args: argparse.Namespace, api: bool):
    """Counts per family and class, and the bad cases to show, of ``n`` generated cases."""
    if not api and n:
        fc.npz_bomb()
    table: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    shown: dict[str, list[str]] = collections.defaultdict(list)
    t0 = time.perf_counter()
    for i in range(n):
        family = families[i % len(families)]
        kind, mutation = run_one(family, args.seed * 1_000_003 + i, args.timeout, args.memory_gb, api)
        cls = kind.split(" (")[0]
        cls = "exit" if cls.startswith("exit") or cls.startswith("killed") else cls
        table[family][cls] += 1
        if cls in BAD and len(shown[cls]) < args.show:
            shown[cls].append(f"{family}: {mutation!r} -> {kind}")
        if (i + 1) % 50 == 0:
            print(f"[{i + 1}/{n} cases, {time.perf_counter() - t0:.0f} s]", file=sys.stderr, flush=True)
    return table, shown


def report(table, shown) -> None:
    """Print the table of counts per family and class, then the bad cases."""
    classes = ["clean error", "accepted", *BAD]
    print("| family | cases | " + " | ".join(classes) + " |")
    print("|---|---:|" + "---:|" * len(classes))
    total: collections.Counter[str] = collections.Counter()
    for family, counts in table.items():
        total.update(counts)
        print(f"| {family} | {sum(counts.values())} | " + " | ".join(str(counts[c]) for c in classes) + " |")
    print(f"| all | {sum(total.values())} | " + " | ".join(str(total[c]) for c in classes) + " |")
    for cls, items in shown.items():
        print(f"\n{cls}:")
        for item in items:
            print("  " + item)


if __name__ == "__main__":
    main()
