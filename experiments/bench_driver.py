"""Speed of the main job: EM-GAIL on the driver, 4 seeds x 400 iterations.

    python experiments/bench_driver.py [--seeds 4] [--iterations 400] [--devices N]

Compilation is measured cold (the persistent compilation cache is off) and reported apart from
training. Targets (issue 2): training <= 60 s after compilation, compilation <= 60 s.
"""

from __future__ import annotations

import argparse
import sys
import tempfile

TRAIN_TARGET_S = 60.0
COMPILE_TARGET_S = 60.0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--algo", default="emgail")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--devices", type=int, default=None, help="host devices (default: cores)")
    args = parser.parse_args(argv)

    from emgail_jax import runtime

    runtime.setup(host_devices=args.devices, cache_dir=None)
    import jax

    from emgail_jax.config import Config
    from emgail_jax.run import train
    from emgail_jax.runs import RunSpec

    config = Config(algo=args.algo, iterations=args.iterations)
    spec = RunSpec("driver", 2, {}, args.algo, args.seeds, 0, None, 0, config)
    with tempfile.TemporaryDirectory() as out:
        summary = train(spec, spec.problem(), out, progress=False)
    final = summary["final"]
    compile_s, train_s = final["compile_time_s"], final["train_time_s"]
    seed_iterations = args.seeds * args.iterations
    print(
        f"devices: {len(jax.devices())} ({jax.devices()[0].platform}), seeds sharded over "
        f"{len(summary['devices'])}"
    )
    print(f"{args.algo} on driver, {args.seeds} seeds x {args.iterations} iterations")
    print(
        f"compile   {compile_s:7.1f} s   target <= {COMPILE_TARGET_S:.0f} s   "
        f"ratio {compile_s / COMPILE_TARGET_S:.2f}"
    )
    print(
        f"train     {train_s:7.1f} s   target <= {TRAIN_TARGET_S:.0f} s   "
        f"ratio {train_s / TRAIN_TARGET_S:.2f}"
    )
    print(
        f"          {1000 * train_s / seed_iterations:7.1f} ms per seed-iteration, "
        f"{final['env_steps'] / train_s:,.0f} env-steps/s"
    )
    print(
        f"final ERD per seed {[round(e, 3) for e in final['erd']]}, "
        f"accuracy {[round(a, 3) for a in final['cluster_accuracy'] or []]}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
