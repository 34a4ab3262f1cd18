"""Train the shipped learned edge refiner (``metasensor/depth/data/edge_refiner.npz``).

Reproducible (:mod:`metasensor.depth.refiner_training`): fixed seeds, one CPU thread,
deterministic algorithms; the benchmark's evaluation scenes (seed 1 at 192 px) and the
photographs of ``scenes.natural_scene`` are never in the training set.

Usage: ``python scripts/train_depth_refiner.py [--scenes N] [--steps N] [--width W] [--seed S]
[--members M] [--out PATH] [--samples FILE] [--validate N]`` (``--members``: fits of the same
samples with the seeds S, S + 1, ..., shipped as one ensemble; ``--samples``: keep the rendered
scenes' samples in FILE, ``.npz``, and reuse them when FILE exists; ``--validate``: score N
held-out scenes of the training family, seeds disjoint from the training ones, after training).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from metasensor.depth.learned import WEIGHTS, EdgeEnsemble, save_refiner  # noqa: E402
from metasensor.depth.refiner_training import (  # noqa: E402
    TRAINED_ON,
    TRAINING_SCENES,
    render_spec,
    samples,
    scene_record,
    train,
    training_specs,
    validate,
)

DEFAULT_OUT = HERE.parent / "src" / "metasensor" / "depth" / "data" / WEIGHTS


def collect(scenes: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples of ``scenes`` training scenes (features, labels, weights)."""
    feats, labels, weights = [], [], []
    t0 = time.perf_counter()
    for i, spec in enumerate(training_specs(scenes, seed)):
        sv = render_spec(spec)
        got = samples(scene_record(sv, TRAINED_ON), sv.disparity)
        if got is not None:
            feats.append(got[0])
            labels.append(got[1])
            weights.append(got[2])
        print(f"scene {i + 1}/{scenes} {spec}: {0 if got is None else len(got[1])} samples "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    return np.concatenate(feats), np.concatenate(labels), np.concatenate(weights)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=TRAINING_SCENES)
    parser.add_argument("--steps", type=int, default=8000)
    parser.add_argument("--width", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--members", type=int, default=2)
    parser.add_argument("--out", default=str(DEFAULT_OUT))
    parser.add_argument("--samples", default=None)
    parser.add_argument("--validate", type=int, default=24,
                        help="held-out scenes of the training family to score (0: none)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    cache = None if args.samples is None else Path(args.samples)
    if cache is not None and cache.exists():
        with np.load(cache, allow_pickle=False) as z:
            feats, labels, weights = z["features"], z["labels"], z["weights"]
    else:
        feats, labels, weights = collect(args.scenes, args.seed)
        if cache is not None:
            np.savez(cache, features=feats, labels=labels, weights=weights)
    print(f"{len(labels)} samples, {labels.mean():.3f} front "
          f"({time.perf_counter() - t0:.0f} s)", flush=True)
    if not 1 <= args.members <= 8:
        parser.error(f"--members must be in [1, 8], got {args.members}")
    fits = [train(feats, labels, weights, steps=args.steps, seed=args.seed + k, width=args.width)
            for k in range(args.members)]
    model = fits[0] if args.members == 1 else EdgeEnsemble(fits)
    print(f"trained in {time.perf_counter() - t0:.0f} s in all")
    save_refiner(model, Path(args.out))
    print(f"-> {args.out}")
    if args.validate > 0:
        rows = validate(model, training_specs(args.validate, args.seed + 1000))
        before, after = (float(np.mean([r[k] for r in rows])) for k in (1, 2))
        print(f"held-out MSE x 100 without / with: {before:.3f} / {after:.3f}; worse on "
              f"{sum(r[2] > r[1] for r in rows)} of {len(rows)} scenes "
              f"({time.perf_counter() - t0:.0f} s in all)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
