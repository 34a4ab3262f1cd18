"""Command line of the recon stage: ``metasensor reconstruct`` (registered on the main app by
:mod:`metasensor.cli`).

The command is declared as one frozen dataclass, :class:`ReconstructArgs` (one field per
option, its combinations checked on construction); :func:`run_reconstruct` reads the inputs
(:mod:`metasensor.recon.inputs`), builds :class:`~metasensor.recon.options.ReconOptions`, runs
:func:`metasensor.reconstruct` and writes the results (:mod:`metasensor.recon.outputs`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from metasensor.cli_options import typed_command
from metasensor.recon.inputs import read_psf_file

__all__ = ["register", "read_psf_file", "ReconstructArgs", "run_reconstruct"]

NOISE_CHOICES = ("auto", "global", "fit", "stored")  # --noise
PRIOR_CHOICES = ("hyper-laplacian", "bm3d")  # --prior

_Path = Path | None


@dataclass(frozen=True)
class ReconstructArgs:
    """The options of ``metasensor reconstruct`` as given on the command line (frozen; the
    combinations that contradict each other are refused on construction)."""

    views: Annotated[Path, typer.Argument(help="view stack (.tif pages u*nnum+v, or .zarr)")]
    out: Annotated[Path, typer.Option("--out", "-o", file_okay=False, help="output folder")]
    psf: Annotated[_Path, typer.Option("--psf", help="PSF bank (HDF5, dataset 'psf')")] = None
    config: Annotated[_Path, typer.Option("--config", help="system configuration TOML")] = None
    method: Annotated[str, typer.Option(
        "--dao", "--method", help="auto: estimate the aberration per block (wave DAO) unless "
        "--system/--zernike/--field-zernike/--psf gives it, keeping the aberration-free bank "
        "where the estimate is negligible | none: no estimate (fastest) | wave | geometric: "
        "DAO in every block, always applied")] = "auto"
    system: Annotated[_Path, typer.Option(
        "--system", help="system aberration (system.h5 from calibrate-aberration): its field "
        "map is used as is, or initialises DAO with --dao wave")] = None
    blocks: Annotated[str, typer.Option(help="multisite blocks, e.g. 4x4")] = "1x1"
    overlap: Annotated[int, typer.Option(help="block overlap in output pixels")] = 20
    solver: Annotated[str | None, typer.Option(
        help="ISA solver: hqs (sparse-gradient prior) | rl (Richardson-Lucy); default hqs, or "
        "rl when --iterations/--subsets is given or the scan step exceeds 5 px")] = None
    register_views: Annotated[bool, typer.Option(
        "--register/--no-register",
        help="register the views against the PSF bank first (for banks that may be off)")
    ] = False
    noise: Annotated[str, typer.Option(
        help="noise model of the data term: global (one weight for every sample) | auto (HQS: "
        "Poisson-Gaussian weights fitted to the views where the fit is reliable, else one "
        "weight) | fit (Poisson-Gaussian, fitted to the views; RL: shifted Poisson) | stored "
        "(Poisson-Gaussian from the views' metadata: gain and read noise, as simulate writes "
        "them)")] = "global"
    noise_estimate: Annotated[str, typer.Option(
        "--noise-estimate", help="HQS: the noise that sets the data weight: differences (the "
        "views' second differences) | poisson-gaussian (the r.m.s. of a Poisson-Gaussian model "
        "fitted once to the views; texture and sparse scans do not raise it) | auto (that fit "
        "where the views follow it, else the differences)")] = "differences"
    scan_exponent: Annotated[float | None, typer.Option(
        "--scan-exponent", min=0.0, help="HQS: e of the data weight's scan factor (d/3)^e, d "
        "the scan step in pixels (no effect at d = 3, the 5 x 5 scan of 15-px lenslets); "
        "default: 2 with the differences, 0.5 with a Poisson-Gaussian noise")] = None
    prior: Annotated[str, typer.Option(
        "--prior", help="HQS's image prior: hyper-laplacian (sparse gradients, the default) | "
        "bm3d (BM3D plug-and-play: keeps texture, tens of times slower, may copy periodic patterns "
        "where the model is poor; needs the optional package bm3d, free for non-commercial "
        "use only: pip install 'metasensor[bm3d]')")
    ] = "hyper-laplacian"
    iterations: Annotated[int | None, typer.Option(help="Richardson-Lucy iterations")] = None
    subsets: Annotated[int | None, typer.Option(help="view subsets per iteration")] = None
    view_radius: Annotated[float | None, typer.Option(
        "--view-radius", help="use the views within this radius (in views) of the centre view; "
        "default: the authors' 113 views (radius 6 for nnum 15); the pupil's radius (7.5) adds "
        "its edge views")] = None
    zernike: Annotated[str | None, typer.Option(
        help="global aberration, e.g. '4:0.5,7:-0.2', or a .npy Noll vector (simulate's "
        "wavefront.npy)")] = None
    field_zernike: Annotated[_Path, typer.Option(
        "--field-zernike", help=".npy (by, bx, J) Noll vectors over the field")] = None
    scheduler: Annotated[str | None, typer.Option(
        help="dask scheduler address tcp://host:port (trusted: dask exchanges pickles over "
        "unauthenticated TCP; use a private network or tls://)")] = None
    device: Annotated[str | None, typer.Option(
        help="cpu or cuda (default: cuda if present)")] = None
    quality: Annotated[str, typer.Option(
        "--quality", help="default: the sparse-gradient solver (HQS), the aberration per --dao | "
        "fast: a preview, Richardson-Lucy (5 iterations), and no aberration estimate unless "
        "--dao wave/geometric asks for one")] = "default"
    workers: Annotated[int | None, typer.Option(
        "--workers", min=1, help="blocks reconstructed at once (threads sharing this process's "
        "torch threads); each block in flight holds its own spectra and work arrays. Default: "
        "one per CPU thread, as many as half the free memory holds (one on CUDA)")] = None
    zarr_out: Annotated[bool, typer.Option(
        "--zarr", help="also stitch into out/image.zarr block by block (large fields)")] = False

    def __post_init__(self) -> None:
        if self.psf is not None and self.config is not None:
            raise ValueError("give either --psf or --config, not both")
        if self.solver == "hqs" and (self.iterations is not None or self.subsets is not None):
            raise ValueError("--iterations/--subsets set Richardson-Lucy's passes; --solver hqs "
                             "takes neither (drop them, or use --solver rl)")
        if self.psf is not None and (self.zernike or self.field_zernike is not None
                                     or self.system is not None):
            raise ValueError("--psf is a complete PSF bank: --zernike/--field-zernike/--system "
                             "would be ignored; give the aberration or the bank, not both")
        if self.system is not None and self.field_zernike is not None:
            raise ValueError("give either --system or --field-zernike, not both")
        if self.noise not in NOISE_CHOICES:
            raise ValueError(f"--noise must be one of {', '.join(NOISE_CHOICES)}, got "
                             f"{self.noise!r}")
        from metasensor.solvers.hqs_options import NOISE_ESTIMATES

        if self.noise_estimate not in NOISE_ESTIMATES:
            raise ValueError(f"--noise-estimate must be one of {', '.join(NOISE_ESTIMATES)}, "
                             f"got {self.noise_estimate!r}")
        self._check_prior()
        if self.hqs_options is not None and (self.isa_solver == "rl" or self.iterations
                                             is not None or self.subsets is not None):
            raise ValueError("--noise-estimate/--scan-exponent/--prior set HQS's options: not "
                             "with Richardson-Lucy (--solver rl, --quality fast, --iterations, "
                             "--subsets)")
        from metasensor.recon.dao_choice import DAO_CHOICES

        if self.quality not in ("default", "fast"):
            raise ValueError(f"--quality must be default or fast, got {self.quality!r}")
        if self.quality == "fast" and self.solver == "hqs":
            raise ValueError("--quality fast runs Richardson-Lucy: drop --solver hqs (or use "
                             "--quality default)")
        if self.method not in DAO_CHOICES:
            raise ValueError(f"--dao must be one of {', '.join(DAO_CHOICES)}, got "
                             f"{self.method!r}")

    @property
    def dao(self) -> str:
        """The DAO mode run: ``--dao``, except that a fast preview skips ``auto``'s estimate."""
        return "none" if self.quality == "fast" and self.method == "auto" else self.method

    def _check_prior(self) -> None:
        """``--prior`` is a known prior, and BM3D's optional package is there."""
        if self.prior not in PRIOR_CHOICES:
            raise ValueError(f"--prior must be one of {', '.join(PRIOR_CHOICES)}, got "
                             f"{self.prior!r}")
        if self.prior == "bm3d":
            from metasensor.priors.external import require_bm3d

            try:
                require_bm3d()
            except ImportError as err:
                raise ValueError(f"--prior bm3d: {err}") from None

    @property
    def hqs_options(self):
        """HQSOptions with ``--prior`` / ``--noise-estimate`` / ``--scan-exponent`` (None: all
        default)."""
        from dataclasses import replace

        from metasensor.solvers.hqs_options import HQSOptions

        if (self.prior, self.noise_estimate, self.scan_exponent) == (
                "hyper-laplacian", "differences", None):
            return None
        base = HQSOptions()
        if self.prior == "bm3d":
            from metasensor.priors.external import bm3d_options

            base = bm3d_options()
        return replace(base, noise_estimate=self.noise_estimate,
                       scan_exponent="auto" if self.scan_exponent is None
                       else self.scan_exponent)

    @property
    def isa_solver(self) -> str | None:
        """The solver asked for (None: the default rule)."""
        return "rl" if self.quality == "fast" else self.solver

    def provenance(self, cfg) -> dict:
        """The inputs' checksums and the settings, for ``summary.json``."""
        from metasensor.io.provenance import provenance

        return provenance({"views": self.views, "psf": self.psf, "config": self.config,
                           "system": self.system, "field_zernike": self.field_zernike},
                          {"method": self.dao, "blocks": self.blocks, "quality": self.quality,
                           "overlap": self.overlap, "solver": self.solver,
                           "noise": self.noise, "noise_estimate": self.noise_estimate,
                           "scan_exponent": self.scan_exponent, "prior": self.prior,
                           "iterations": self.iterations, "subsets": self.subsets,
                           "view_radius": self.view_radius, "zernike": self.zernike,
                           "config": cfg.to_dict()})


def _noise_model(args: ReconstructArgs, inputs):
    """``--noise`` as a ReconOptions value: "auto", "global", "fit" or the stored model."""
    if args.noise != "stored":
        return args.noise
    if inputs.noise is None:
        raise ValueError(f"--noise stored: {args.views} holds no gain and read noise in its "
                         "metadata; use --noise fit")
    return inputs.noise


def _recon_options(args: ReconstructArgs, inputs, target):
    """The reconstruction's settings from the command line."""
    from metasensor.recon.options import ReconOptions

    bank = inputs.bank
    return ReconOptions(overlap=args.overlap, iterations=args.iterations, subsets=args.subsets,
                        solver=args.isa_solver, register=args.register_views,
                        noise_model=_noise_model(args, inputs), solver_options=args.hqs_options,
                        view_radius=args.view_radius, device=args.device, psf=bank,
                        scheduler=args.scheduler,
                        num_workers="auto" if args.workers is None else args.workers,
                        out=target, progress=True)


def _zarr_target(args: ReconstructArgs, cfg, stack):
    """The staged output folder and the zarr array in it that the blocks are stitched into."""
    from metasensor.io.atomic import StagedFolder
    from metasensor.io.interrupt import quiet_zarr
    from metasensor.recon.outputs import RESULT_FILES

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread
    d = cfg.scan_step_px
    shape = (stack.shape[2] * d, stack.shape[3] * d)
    staged = StagedFolder(args.out, RESULT_FILES)  # complete, or not at all
    target = zarr.open_array(str(staged.path / "image.zarr"), mode="w", shape=shape,
                             chunks=(min(1024, shape[0]), min(1024, shape[1])), dtype="f4",
                             fill_value=0.0)
    return staged, target


def _say_done(rec, written: list[Path]) -> None:
    if rec.registration_zernike is not None:
        applied = np.any(rec.registration_zernike != 0, axis=-1)
        worst = float(np.abs(rec.registration_zernike).max())
        typer.echo(f"registration: PSF banks moved in {int(applied.sum())} of {applied.size} "
                   f"block(s) (largest wavefront term {worst:.3f} λ; registration_px and "
                   "registration_zernike in summary.json)")
    typer.echo(f"reconstructed {rec.image.shape[0]}x{rec.image.shape[1]} px in "
               f"{rec.seconds:.1f} s -> {', '.join(str(p) for p in written)}")


def _say_dao(args: ReconstructArgs, inputs) -> None:
    """One line on stderr: whether the aberration is estimated, and why."""
    from metasensor.optics.psf_io import parse_zernike
    from metasensor.recon.dao_choice import choose_dao

    z = parse_zernike(args.zernike)
    given = inputs.field_zernike is not None or (z is not None and bool(np.any(z)))
    bank = inputs.bank is not None
    unavailable = None
    if args.dao == "auto" and not (given or bank):
        from metasensor.dao.estimate import dao_unavailable

        unavailable = dao_unavailable(inputs.config, inputs.config.view_mask(args.view_radius))
    choice = choose_dao(args.dao, aberration_given=given, bank_given=bank,
                        unavailable=unavailable)
    typer.echo(f"aberration: {choice.reason}", err=True)


def run_reconstruct(args: ReconstructArgs) -> None:
    """Reconstruct the all-in-focus image from views (ISA; multisite blocks through Dask).

    By default the aberration is estimated per block (DAO), as the paper does, unless a system
    calibration or an aberration is given; --dao none skips the estimate.

    Example: metasensor reconstruct cap/views.tif --blocks 4x4 --out result/

    Known optics: metasensor reconstruct views.tif --system system.h5 --out result/
    """
    from metasensor.cli_options import parse_pair
    from metasensor.io.atomic import StagedFolder
    from metasensor.io.views import description
    from metasensor.optics.psf_io import parse_zernike
    from metasensor.recon.api import reconstruct
    from metasensor.recon.inputs import read_inputs
    from metasensor.recon.outputs import RESULT_FILES, image_meta, write_outputs

    inputs = read_inputs(args)
    cfg, stack = inputs.config, inputs.stack
    staged, target = _zarr_target(args, cfg, stack) if args.zarr_out else (None, None)
    _say_dao(args, inputs)
    try:
        rec = reconstruct(stack, cfg, method=args.dao, zernike=parse_zernike(args.zernike),
                          field_zernike=inputs.field_zernike,
                          blocks=parse_pair(args.blocks, "--blocks"),
                          options=_recon_options(args, inputs, target))
    except BaseException:
        if staged is not None:
            staged.discard()
        raise
    if target is not None:
        target.attrs.update(description(cfg, **image_meta(rec, inputs.origin)))
    else:
        staged = StagedFolder(args.out, RESULT_FILES)  # an earlier run's image.zarr goes
    if inputs.bank_zernike is not None:  # the aberration the given bank was made with
        z = inputs.bank_zernike
        rec.zernike = np.zeros(rec.zernike.shape[:2] + (z.size,), np.float32) + z
    written = [args.out / p.name for p in write_outputs(
        staged.path, rec, stack, inputs.origin, provenance=args.provenance(cfg))]
    staged.commit()
    if target is not None:
        from metasensor.io.interrupt import quiet_zarr

        zarr = quiet_zarr()  # Ctrl-C reaches the main thread
        rec.image = zarr.open_array(str(args.out / "image.zarr"), mode="r")
        written.insert(1, args.out / "image.zarr")
    _say_done(rec, written)


def register(app: typer.Typer) -> None:
    """Add this stage's commands to ``app``."""
    app.command("reconstruct")(typed_command(ReconstructArgs, run_reconstruct))
