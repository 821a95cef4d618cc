"""Many views of one stored solution across a Ray cluster, and how throughput grows with workers.

    python python/examples/ray_views.py data/cloud.toml --views 32 --workers 1 2

solves the scene once (or loads --solution), then renders an orbit of --views views on each
worker count in turn (one thread per worker) and once in this process with every core, and
prints views per second as a Markdown table. On a real cluster start Ray there and pass
--address auto; the solution travels once through Ray's object store.
"""

import argparse
import os
import time

import ray

import volrad
from volrad.distributed import ViewPool


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", help="scene file to solve (ignored with --solution)")
    parser.add_argument("--solution", help="a stored solution file instead of solving")
    parser.add_argument("--views", type=int, default=32)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--height", type=int, default=192)
    parser.add_argument("--address", help="a running Ray cluster (default: start a local one)")
    args = parser.parse_args()

    if args.solution:
        solution = volrad.Solution.load(args.solution)
    else:
        solution = volrad.Scene.from_file(args.scene).solve(progress=True)
    cameras = [
        dict(cam, width=args.width, height=args.height) for cam in solution.orbit(args.views)
    ]
    if args.address:
        ray.init(address=args.address, log_to_driver=False)
    else:
        ray.init(num_cpus=max(args.workers), include_dashboard=False, log_to_driver=False)

    cores = os.cpu_count()
    print(f"{args.views} views of {args.width}×{args.height}, {cores} cores")
    print("| renderer | views/s | speed-up |")
    print("|---|---|---|")
    # The first view builds the solution's render caches: left out, as the pools' start-up.
    solution.render(cameras[0])
    start = time.perf_counter()
    reference = [solution.render(cam) for cam in cameras]
    single = args.views / (time.perf_counter() - start)
    print(f"| one process, {cores} threads | {single:.2f} | 1.00 |")
    for workers in args.workers:
        start = time.perf_counter()
        with ViewPool(solution, workers=workers) as pool:
            # Each worker loads the solution once; its start-up (with a first view each) is
            # printed apart from the figure, which is the steady throughput of a pool that
            # renders batch after batch.
            pool.render(cameras[:workers])
            startup = time.perf_counter() - start
            start = time.perf_counter()
            images = pool.render(cameras)
            rate = args.views / (time.perf_counter() - start)
        assert all((a == b).all() for a, b in zip(images, reference)), "a view differs"
        print(
            f"| Ray, {workers} worker(s) × 1 thread | {rate:.2f} | {rate / single:.2f} |"
            f" (start-up {startup:.2f} s)"
        )

if __name__ == "__main__":
    main()
