"""The planning kernels compiled ahead of time into two extension modules (numba's pycc).

`uav-robots build` (`python -m uav_agent.planning.build.aot`) builds them in two steps, each in
processes of their own:

1. **record**: the planners run on tiny instances with the kernels interpreted
   (`compile/jit.py`'s record mode), every planner, both connectivities, narrow and wide
   distance rows; each call of a kernel from Python notes its argument types;
2. **compile**: numba's pycc compiles every recorded (kernel, argument types) pair, with
   the kernels they call inlined or linked in, into a shared library with the system's
   C compiler, for this machine's CPU, releasing the GIL while a kernel runs: two
   libraries (two kernel families) side by side on two cores.

The libraries and their manifest (kernel -> argument kinds -> exported function) go to
`compile.cache.build_dir()` under `compile.cache.build_name()` (the kernel sources, Python, NumPy and the
CPU), the manifest last: a process that finds it loads the kernels without numba; a
changed source names another build. A machine without Linux, a C compiler or Python's
headers keeps numba's JIT. Nothing builds by itself: `uav-robots build` is run once.
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import pickle
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
import warnings
from pathlib import Path

from ..registry import REFINE_KERNELS, REFINE_LIBRARY, SPECS

BUILD_TIMEOUT_S = 1800.0


def _record_workload() -> None:
    """Every kernel call the planners make from Python, on tiny instances (record mode)."""
    import numpy as np

    from ..mapf import distances
    from ..mapf.distances import clear_cache, compile_problem
    from ..mapf.lacam import search
    from ..mapf.prioritized import guide_paths
    from ..mapf.refine import improve, refine, trimmed
    from ..mapf.scatter import routes
    from ..pipeline import plan_mission
    from ..registry import PLANNERS
    from ..types import Limits, Problem

    free = np.ones((7, 9), dtype=bool)
    free[2, 1:8] = False
    free[4, 1:4] = False
    free[4, 5:8] = False
    starts = [(0, 0), (8, 0), (0, 6), (8, 6), (4, 3)]
    goals = [(8, 6), (0, 6), (8, 0), (0, 0), (0, 3)]
    narrow = distances.UNREACHABLE_16
    for wide in (False, True):
        # wide rows (int32) are what a maze longer than 65,534 steps needs; a tiny one asks for them here
        distances.UNREACHABLE_16 = 2 if wide else narrow
        clear_cache()
        for conn in (4, 8):
            for planner in PLANNERS:
                for assign in ("optimal", "none"):
                    plan_mission(free, starts, goals, planner=planner, connectivity=conn, assign=assign,
                                 time_limit=60.0, fallback=True)
            problem = Problem(free, starts, goals, connectivity=conn)
            inst = compile_problem(problem)
            found = guide_paths(inst, Limits(60.0), 10_000)
            buf, poff, plen, _ = found
            search(inst, Limits(60.0), guides=(buf, poff, plen))
            search(inst, Limits(60.0), routes=routes(inst, 60.0)[:2])
            hist = search(inst, Limits(60.0))
            refine(inst, *trimmed(inst, hist), 0.05)
            improve(problem, [[(0, 0)] * 3 + [(1, 0)]] + [[s, s] for s in starts[1:]], 0.05)
    distances.UNREACHABLE_16 = narrow
    # The repair among movers (avoid.py), whose kernels the JIT compiles only in a mission with movers.
    from ..avoid import warm_up as warm_up_repair

    warm_up_repair()


def record(out: Path) -> None:
    from ..compile import jit
    if jit.MODE != "record":
        raise SystemExit("run the record step with UAV_ROBOTS_KERNELS=record and NUMBA_DISABLE_JIT=1")
    import numpy as np
    # uint64 hashing and random generators wrap around by design, as they do compiled
    with warnings.catch_warnings(), np.errstate(over="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        _record_workload()
    out.write_bytes(pickle.dumps(jit.RECORDED))


def _modules(kernels) -> set[str]:
    return {f"uav_agent.planning.{k.rsplit('.', 1)[0]}." for k in kernels}


# Two libraries, compiled side by side on two cores: each family with the kernels it links in
SECOND_LIBRARY = tuple(sorted(
    _modules(k for s in SPECS if s.aot_library == 1 for k in s.kernels)
    | (_modules(REFINE_KERNELS) if REFINE_LIBRARY == 1 else set())))


def compile_recorded(records: dict, out_dir: Path, name: str) -> dict[str, list]:
    """Compiles the recorded kernels into `out_dir/name*.so`: {kernel: [[argument kinds, export]]}."""
    from numba.core.compiler import Flags
    import numba.pycc.compiler as pycc_compiler
    from numba.pycc import CC

    class _NoGil(Flags):
        # every kernel lets the interpreter's other threads run (the UAV's links, the BFS threads)
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.release_gil = True

    cc = CC(name)
    cc.target_cpu = "host"
    work = Path(tempfile.mkdtemp(prefix="out-"))     # TMPDIR: the build's own work directory
    cc.output_dir = str(work)
    exports: dict[str, list] = {}
    for i, ((kernel, key), argtypes) in enumerate(sorted(records.items(), key=lambda kv: repr(kv[0]))):
        module, function = kernel.rsplit(".", 1)
        dispatcher = getattr(importlib.import_module(module), function)
        export = f"k{i}"
        cc.export(export, tuple(argtypes))(dispatcher.py_func)
        exports.setdefault(kernel, []).append([repr(key), export])
    pycc_compiler.Flags = _NoGil
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cc.compile()
    finally:
        pycc_compiler.Flags = Flags
    built = next(work.glob(f"{name}.*"))
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.move(str(built), out_dir / built.name)
    shutil.rmtree(work, ignore_errors=True)
    return {"file": built.name, "kernels": exports}


class BuildError(Exception):
    pass


def _last_line(path: Path) -> str:
    """A child's error: the last line naming an exception (what follows it can be advice), else its last line."""
    lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    named = [ln for ln in lines if re.match(r"^[A-Za-z_.]*(Error|Exception)\b", ln)]
    return (named or lines or ["no message"])[-1]


def _work_dir(out_dir: Path) -> Path:
    """A work directory of this process's own under `out_dir`, after removing those of builds
    that were killed (their process is gone): pycc and the C compiler leave theirs behind."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob(".work-*"):
        try:
            os.kill(int(old.name.split("-", 1)[1]), 0)
        except (ValueError, ProcessLookupError):
            shutil.rmtree(old, ignore_errors=True)
        except PermissionError:
            pass
    work = out_dir / f".work-{os.getpid()}"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    return work


def build(timeout: float = BUILD_TIMEOUT_S) -> Path:
    """Records, then compiles two libraries side by side, each step in child processes; writes
    the manifest last and returns its path."""
    from ..compile.cache import build_dir, build_name
    from .child import child_env
    name = build_name()
    out_dir = build_dir()
    tmp = _work_dir(out_dir)
    try:
        rec = tmp / "recorded.pkl"
        with open(tmp / "record.err", "w") as err:
            done = subprocess.run([sys.executable, "-m", "uav_agent.planning.build.aot", "--record", str(rec)],
                                  env=child_env(UAV_ROBOTS_KERNELS="record", NUMBA_DISABLE_JIT="1",
                                                 TMPDIR=str(tmp)),
                                  timeout=timeout, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
        if done.returncode != 0:
            raise BuildError(f"recording the kernels' signatures failed: {_last_line(tmp / 'record.err')}")
        records = pickle.loads(rec.read_bytes())
        parts = [{k: v for k, v in records.items() if k[0].startswith(SECOND_LIBRARY) == second}
                 for second in (False, True)]
        jobs = []
        for i, part in enumerate(parts):
            (tmp / f"part{i}.pkl").write_bytes(pickle.dumps(part))
            with open(tmp / f"part{i}.err", "w") as err:
                jobs.append(subprocess.Popen(
                    [sys.executable, "-m", "uav_agent.planning.build.aot", "--compile", str(tmp / f"part{i}.pkl"),
                     "--name", f"{name}_{i}", "--out", str(out_dir)],
                    env=child_env(UAV_ROBOTS_KERNELS="jit", TMPDIR=str(tmp)), stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL, stderr=err))
        try:
            for i, job in enumerate(jobs):
                if job.wait(timeout=timeout) != 0:
                    raise BuildError(f"compiling library {i} failed: {_last_line(tmp / f'part{i}.err')}")
        except subprocess.TimeoutExpired:
            raise BuildError(f"the build took over {timeout:g} s") from None
        finally:
            for job in jobs:
                if job.poll() is None:
                    job.kill()
                    job.wait()
        libraries = [json.loads((tmp / f"part{i}.json").read_text()) for i in range(len(parts))]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    tmp_manifest = out_dir / f".{name}.json.tmp"
    tmp_manifest.write_text(json.dumps({"libraries": libraries}))
    os.replace(tmp_manifest, out_dir / f"{name}.json")     # last: its presence means a whole build
    for old in out_dir.glob("kernels_*"):       # builds of other sources are dead weight
        if not old.name.startswith(name):
            old.unlink(missing_ok=True)
    return out_dir / f"{name}.json"


def missing_tools() -> str | None:
    """What the build needs and this machine lacks (None: nothing)."""
    if not sys.platform.startswith("linux"):
        return "Linux (the build is for Linux only)"
    if shutil.which(os.environ.get("CC", "cc")) is None:
        return "a C compiler (`cc`)"
    if not (Path(sysconfig.get_paths()["include"]) / "Python.h").is_file():
        return "Python's C headers (Python.h; Debian: python3-dev)"
    return None


def build_once() -> int:
    """`build` unless another process is building: 0 when built (or being built), 1 on failure."""
    from ..compile.lock import kernel_lock

    lacking = missing_tools()
    if lacking is not None:
        print(f"error: the ahead-of-time build needs {lacking}; the planners keep numba's JIT", file=sys.stderr)
        return 1
    began = time.perf_counter()
    with kernel_lock(wait=False, what="aot") as mine:
        if not mine:
            print("another process is building the planner kernels ahead of time")
            return 0
        try:
            manifest = build()
        except (BuildError, subprocess.TimeoutExpired, OSError) as exc:
            print(f"error: the ahead-of-time build failed ({exc}); the planners keep numba's JIT",
                  file=sys.stderr)
            return 1
    print(f"planner kernels built ahead of time in {time.perf_counter() - began:.1f} s ({manifest.parent})")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m uav_agent.planning.build.aot",
                                description="Compile the planning kernels ahead of time (numba pycc + the C compiler).")
    p.add_argument("--record", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--compile", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--name", help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.record:
        record(args.record)
        return 0
    if args.compile:
        library = compile_recorded(pickle.loads(args.compile.read_bytes()), args.out, args.name)
        args.compile.with_suffix(".json").write_text(json.dumps(library))
        return 0
    return build_once()


if __name__ == "__main__":
    sys.exit(main())
