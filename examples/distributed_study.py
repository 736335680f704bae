"""A Monte Carlo study spread over several processes with `jax.distributed`.

Every process runs this same script; process 0 also hosts the coordinator. Each
batch of samples is one global array sharded over the devices of all processes,
and process 0 writes the chunks to the shared store. Two processes on one machine:

    python examples/distributed_study.py --store study --process-id 0 &
    python examples/distributed_study.py --store study --process-id 1

On a cluster, start one process per machine with `--coordinator HOST:PORT` of
process 0 and `--num-processes N` (the store must be on a shared file system).
Re-running the same commands after a crash resumes from the last complete chunk.
Open the result with `elasticoop.montecarlo.open_study("study")`.
"""

import argparse

import jax
import numpy as np


def make_study(n_samples: int = 64, t_end: float = 0.5):
    """Grasp stiffness and object mass uncertain; peak grasp forces and the
    object's pose over time kept."""
    import elasticoop as eo
    from elasticoop import montecarlo as mc

    up = (0.0, np.pi / 2, 0.0)
    y0 = np.array([[0, 0, 1, *up], [-0.5, 0, 1, *up], [0.5, 0, 1, *up]])
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    grasps = [
        eo.Connection(
            0,
            i,
            stiffness=(800, 900, 1000, 20, 25, 30),
            damping=(3, 2.5, 2, 0.05, 0.04, 0.06),
        )
        for i in (1, 2)
    ]
    model = eo.MobileModel(bodies, grasps).with_unloaded_state(y0)
    lift = np.zeros((2, 6))
    lift[:, 2] = 12.0  # [N], a little less than the weight
    return mc.Study(
        model,
        y0,
        np.zeros_like(y0),
        np.linspace(0.0, t_end, 11),
        forces=lift,
        parameters=[
            mc.Parameter(
                "stiffness",
                lambda m: m.stiffness,
                mc.LogNormal(0.0, 0.2),
                relative=True,
            ),
            # the object's mass uncertain, the contact bodies' fixed (low = high)
            mc.Parameter(
                "mass",
                lambda m: m.bodies.mass,
                mc.Uniform((1.8, 0.3, 0.25), (2.2, 0.3, 0.25)),
            ),
        ],
        outputs={"peak_force": mc.peak_elastic_force(), "pose": mc.object_pose()},
        n_samples=n_samples,
        key=2024,
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", required=True, help="result folder (shared)")
    parser.add_argument("--process-id", type=int, required=True)
    parser.add_argument("--num-processes", type=int, default=2)
    parser.add_argument("--coordinator", default="localhost:12355")
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--t-end", type=float, default=0.5)
    parser.add_argument("--batch-width", type=int, default=8)
    parser.add_argument("--chunk-size", type=int, default=32)
    args = parser.parse_args()

    jax.distributed.initialize(
        coordinator_address=args.coordinator,
        num_processes=args.num_processes,
        process_id=args.process_id,
    )
    from elasticoop import montecarlo as mc

    study = make_study(args.samples, args.t_end)
    ds = mc.run_study(
        study,
        args.store,
        batch_width=args.batch_width,
        chunk_size=args.chunk_size,
        progress=args.process_id == 0,
    )
    if args.process_id == 0:
        print(mc.summary(ds))
        print(mc.statistics(ds, "peak_force"))
    jax.distributed.shutdown()


if __name__ == "__main__":
    main()
