"""Mutation testing of the core maths with mutmut's mutation operators (not in CI: hours of CPU).

    python3 -m venv /tmp/mutvenv && /tmp/mutvenv/bin/pip install "mutmut==2.5.1"
    /tmp/mutvenv/bin/python benchmarks/mutation.py [--per-module 40] [--seed 0] [--modules trees/registration.py ...]

mutmut 2 generates the mutants (operators, numbers, comparisons, keywords, ...); this driver applies one at a
time to a COPY of the sources (``--work``, default /tmp/torch4dtree-mutation: this checkout is never touched),
runs the fast tests paired with its module in the project's venv (``--python``, niced) and records killed / survived /
timeout with the mutant's diff in a JSON-lines file. With ``--per-module N`` it runs a seeded uniform sample of
N mutants per module (all of them with 0): a full run is ~3,400 mutants at ~10 s each, too much for a shared
2-core machine. String-literal mutants (``"XX...XX"``: error messages) are left out: they cannot change results.
The numba kernels (dp_numba.py, refinement.py) run with NUMBA_DISABLE_JIT=1 on tiny inputs, as recompiling them
per mutant takes minutes. One process, one thread.
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
import random
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# module -> pytest arguments (the fast tests that should kill its mutants)
TESTS: dict[str, list[str]] = {
    "trees/solver.py": ["tests/trees/test_optimality.py",
                        "tests/trees/test_registration.py::test_map_points_recovers_known_warps[none-0]",
                        "tests/trees/test_registration.py::test_invariance_with_default_settings_moderate_warps[14]"],
    "curves/dp_torch.py": ["tests/curves/test_warping.py::test_dp_is_the_exact_lattice_optimum",
                           "tests/curves/test_warping.py::test_torch_and_numba_dp_agree_on_rough_pairs[9-6-None-None]",
                           "tests/curves/test_warping.py::test_torch_and_numba_dp_agree_on_rough_pairs[17-4-2-8]"],
    "curves/rotation.py": ["tests/curves/test_warping.py", "-k", "(every_rotation_is_proper and numba) or "
                           "optimal_rotation_is_optimal or invariant_to_random"],
    "curves/srvf.py": ["tests/curves/test_curves.py",
                       "tests/curves/test_warping.py::test_moving_curve_with_another_number_of_points",
                       "tests/curves/test_warping.py::test_dp_is_the_exact_lattice_optimum"],
    "curves/warps.py": ["tests/curves/test_warping.py", "-k",
                        "warp_utilities or lattice_optimum or neighbourhood or proper"],
    "trees/correspondence.py": ["tests/trees/test_registration.py", "-k",
                                "map_points or (invariance_to_rotation and none and 1)"],
    "trees/aligned.py": ["tests/trees/test_optimality.py", "tests/trees/test_geodesic.py",
                         "tests/trees/test_registration.py", "-k",
                         "not pheno4d and not synthetic and not cli and not pairwise and not invariance and not "
                         "residual and not map_points and not benchmarks"],
    "curves/register.py": ["tests/curves/test_warping.py", "-k",
                           "lattice_optimum or agree_on_rough_pairs or identity_pair or recovers or moving_curve or "
                           "invariant or (proper and numba)"],
    "curves/kernels_numba.py": ["tests/curves/test_warping.py::test_dp_is_the_exact_lattice_optimum",
                           "tests/trees/test_optimality.py::test_the_lattice_is_what_brute_force_enumerates",
                           "tests/curves/test_warping.py::test_torch_and_numba_dp_agree_on_rough_pairs[9-6-None-None]",
                           "tests/curves/test_warping.py::test_every_rotation_is_proper[so3-numba]"],
}
NO_JIT = {"curves/kernels_numba.py", "curves/refinement.py"}


def mutants(path: Path) -> list[tuple[object, str]]:
    """Every mutmut mutant of a file as ``(MutationID, mutated source)``, string-literal mutants left out."""
    from mutmut import Context, list_mutations, mutate

    src = path.read_text()
    out = []
    for mid in list_mutations(Context(source=src, filename=str(path))):
        new, n = mutate(Context(source=src, filename=str(path), mutation_id=mid))
        if n != 1 or new == src:
            continue
        old_line = src.splitlines()[mid.line_number]
        new_line = new.splitlines()[mid.line_number]
        if new_line.replace('XX"', '"').replace("\"XX", "\"").replace("XX'", "'").replace("'XX", "'") == old_line:
            continue  # a string literal wrapped in XX: messages only
        out.append((mid, new))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--modules", nargs="*", default=list(TESTS))
    p.add_argument("--per-module", type=int, default=40, help="sampled mutants per module (0 = all)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--nice", type=int, default=5)
    p.add_argument("--work", default="/tmp/torch4dtree-mutation")
    p.add_argument("--python", default=str(REPO / ".venv/bin/python") if (REPO / ".venv").exists()
                   else "/work/main/.venv/bin/python")
    p.add_argument("--out", default=None, help="JSON lines of results (default: WORK/results.jsonl)")
    a = p.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    for name in ("torch4dtree", "tests"):
        shutil.rmtree(work / name, ignore_errors=True)
        # with __pycache__ and mtimes (copy2): numba's on-disk cache stays valid, no recompilation
        shutil.copytree(REPO / name, work / name)
    out = Path(a.out or work / "results.jsonl")
    env = {**os.environ, "PYTHONPATH": str(work), "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    rng = random.Random(a.seed)
    for mod in a.modules:
        target = work / "torch4dtree" / mod
        original = target.read_text()
        cmd = ["nice", "-n", str(a.nice), a.python, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *TESTS[mod]]
        menv = {**env, **({"NUMBA_DISABLE_JIT": "1"} if mod in NO_JIT else {})}
        t0 = time.perf_counter()
        base = subprocess.run(cmd, cwd=work, env=menv, capture_output=True, text=True)
        baseline = time.perf_counter() - t0
        if base.returncode != 0:
            print(f"{mod}: the tests fail before mutation, skipped\n{base.stdout[-2000:]}", flush=True)
            continue
        todo = mutants(target)
        total = len(todo)
        if a.per_module and a.per_module < total:
            todo = rng.sample(todo, a.per_module)
        print(f"=== {mod}: {total} mutants (strings excluded), running {len(todo)}; baseline {baseline:.1f} s",
              flush=True)
        for mid, new in todo:
            target.write_text(new)
            t0 = time.perf_counter()
            try:
                r = subprocess.run(cmd, cwd=work, env=menv, capture_output=True, text=True,
                                   timeout=max(60.0, 5 * baseline))
                status = "survived" if r.returncode == 0 else "killed"
            except subprocess.TimeoutExpired:
                status = "timeout"  # counted as killed (an infinite loop is caught)
            finally:
                target.write_text(original)
            diff = "".join(difflib.unified_diff(original.splitlines(True), new.splitlines(True), n=0))
            rec = {"module": mod, "line": mid.line_number + 1, "status": status,
                   "seconds": round(time.perf_counter() - t0, 1), "diff": diff.split("\n", 2)[-1]}
            with out.open("a") as f:
                f.write(json.dumps(rec) + "\n")
            print(f"{status:8s} {mod}:{rec['line']}  {rec['diff'].strip().splitlines()[-1][:100]}", flush=True)
    summarise(out)


def summarise(path: Path) -> None:
    """Score per module from the results file."""
    rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    mods = sorted({r["module"] for r in rows})
    for m in mods + ["all"]:
        sel = [r for r in rows if m in ("all", r["module"])]
        killed = sum(r["status"] != "survived" for r in sel)
        print(f"{m:28s} {killed:4d} / {len(sel):4d} killed ({100 * killed / max(len(sel), 1):.0f} %)")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--summary":
        summarise(Path(sys.argv[2]))
    else:
        main()
