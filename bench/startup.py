"""Start-up cost in a fresh process: import, Taichi init, scene build, and the first call of each
stepping path (kernel compilation or loading from the offline cache) against the second call.

Run by ``python -m bench`` three times with the same ``ELASTIC_CACHE_DIR``: first with an empty
directory (cold: every kernel is compiled) ending with a plain exit, as the engine's programs do;
then again (if that exit wrote Taichi's offline cache, this run loads its kernels; if not, it
compiles again), this time ending with ``ti.reset()``, which writes the cache; then a third
time (warm: kernels load from the cache).  Prints one JSON object (or writes it to ``--json``).

    python -m bench.startup [--json PATH] [--reset-at-exit]
"""
import time

T0 = time.perf_counter()

import argparse  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402

from bench.output import emit_json  # noqa: E402


def _first_and_second(fn):
    t0 = time.perf_counter()
    fn()
    t1 = time.perf_counter()
    fn()
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.startup", description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", help="write the result here instead of stdout")
    ap.add_argument("--side", type=int, default=32, help="cloth vertices per side (default 32)")
    ap.add_argument("--reset-at-exit", action="store_true",
                    help="call ti.reset() before exiting (Taichi writes its offline cache then; a plain exit "
                         "may leave it unwritten)")
    args = ap.parse_args(argv)

    out = {"cache_dir": os.environ.get("ELASTIC_CACHE_DIR", "")}
    t = time.perf_counter()
    from engine import runtime  # first: it silences Taichi's banner before importing taichi

    import taichi as ti
    from engine.integrators import BackwardEuler, Stepper, get
    from engine.scenes import Rod
    from engine.scenes import cloth
    out["import_s"] = time.perf_counter() - t
    out["interpreter_to_import_s"] = t - T0
    t = time.perf_counter()
    info = runtime.init()
    out["init_s"] = time.perf_counter() - t
    out["threads"], out["fp"] = info.threads, info.fp
    t = time.perf_counter()
    c = cloth(args.side, E=1e3, rho=0.1, B=1e-4)
    st = c.model.make_state()
    out["scene_s"] = time.perf_counter() - t

    paths = {}
    se = get("symplectic-euler")
    se_stepper = Stepper(c.model, se)
    paths["explicit-step"] = _first_and_second(lambda: (se_stepper.step(st, 1e-5, 1), ti.sync()))
    for solver in ("pcg", "cholesky"):
        be = Stepper(c.model, BackwardEuler(solver=solver, tol=1e-5, newton_iterations=1, line_search=False))
        paths[f"backward-euler-{solver}"] = _first_and_second(lambda: (be.advance(st, 1e-3), ti.sync()))
    rod = Rod.uniform(1000, pinned=[0])
    rs = rod.new_state()
    paths["rod-run"] = _first_and_second(lambda: (rod.run(rs, 0.5 * rod.stable_dt(), 10), ti.sync()))
    out["paths"] = {k: {"first_s": a, "second_s": b, "compile_s": max(a - b, 0.0)} for k, (a, b) in paths.items()}
    out["first_calls_s"] = sum(a for a, _ in paths.values())
    out["compile_total_s"] = sum(max(a - b, 0.0) for a, b in paths.values())
    out["process_s"] = time.perf_counter() - T0
    out["reset_at_exit"] = bool(args.reset_at_exit)
    if args.reset_at_exit:
        ti.reset()
    return emit_json(out, args.json)


if __name__ == "__main__":
    sys.exit(main())
