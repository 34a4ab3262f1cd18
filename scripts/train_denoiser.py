"""Train the shipped CNN denoiser (``metasensor/priors/data/denoiser.npz``) on dead leaves.

Reproducible (:mod:`metasensor.priors.training`): fixed seed, one CPU thread, deterministic
algorithms; natural photographs are never in the training set.

Usage: ``python scripts/train_denoiser.py [--steps N] [--images N] [--seed S] [--out PATH]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))

from metasensor.priors.denoiser import WEIGHTS, save_weights  # noqa: E402
from metasensor.priors.training import train, validate  # noqa: E402

DEFAULT_OUT = HERE.parent / "src" / "metasensor" / "priors" / "data" / WEIGHTS


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=800)
    parser.add_argument("--images", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(DEFAULT_OUT))
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    model = train(steps=args.steps, images=args.images, seed=args.seed)
    print(f"trained in {time.perf_counter() - t0:.0f} s;", validate(model))
    save_weights(model, Path(args.out))
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
