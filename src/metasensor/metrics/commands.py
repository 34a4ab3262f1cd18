"""Command-line commands of the metrics stage (registered on the main app by metasensor.cli)."""

from pathlib import Path

import numpy as np
import typer

__all__ = ["register", "read_image", "parse_roi"]


def read_image(path: str | Path, what: str = "image") -> np.ndarray:
    """Read a 2-D image from a TIFF (first/only page; singleton axes dropped) or ``.npy``."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{what} file not found: {p}")
    from metasensor.io.tiff import TiffReadError, read_tiff

    try:
        arr = np.load(p, allow_pickle=False) if p.suffix.lower() == ".npy" else read_tiff(p)
    except TiffReadError as exc:  # already one line naming the file
        raise ValueError(f"{what}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file
        raise ValueError(f"cannot read {what} {p}: {exc}".splitlines()[0]) from None
    arr = np.squeeze(np.asarray(arr))
    if arr.dtype.kind not in "buif":
        raise ValueError(f"{what} {p} must hold real numbers, got dtype {arr.dtype}")
    if arr.ndim != 2:
        raise ValueError(f"{what} {p} must hold one 2-D image, got shape {arr.shape}")
    return arr.astype(np.float32, copy=False)


def parse_roi(text: str) -> tuple[int, int, int, int]:
    """``"y0,y1,x0,x1"`` -> a tuple of four ints (half-open pixel bounds)."""
    parts = [p for p in text.replace(" ", "").split(",") if p]
    try:
        vals = tuple(int(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 4:
        raise ValueError(f"--roi must be y0,y1,x0,x1 (four integers), got {text!r}")
    return vals  # type: ignore[return-value]


def register(app: typer.Typer) -> None:
    """Add this stage's commands to app."""

    @app.command("evaluate")
    def evaluate_cmd(
        result: Path = typer.Argument(..., help="Result image (2-D TIFF or .npy)."),
        truth: Path | None = typer.Option(None, "--truth", help="Ground-truth image, same shape."),
        chart: bool = typer.Option(False, "--chart", help="Find slanted-edge squares (on the "
                                   "truth if given) and measure the MTF across the field."),
        roi: list[str] | None = typer.Option(None, "--roi", help="Slanted-edge ROI y0,y1,x0,x1 "
                                             "(repeat the option for several)."),
        pixel_pitch: float | None = typer.Option(None, "--pixel-pitch",
                                                 help="Pixel pitch in metres (adds lp/mm)."),
        data_range: float | None = typer.Option(
            None, "--data-range", help="Peak-to-peak range for PSNR/SSIM (default: the truth's "
            "max - min; needed for a constant truth)."),
        out: Path | None = typer.Option(None, "--out", "-o", file_okay=False,
                                        help="Output folder (default: "
                                        "RESULT's folder / <RESULT stem>_evaluation)."),
    ) -> None:
        """PSNR, SSIM and slanted-edge MTF (ISO 12233) of a result image.

        Writes evaluation.json, evaluation.csv (one row per MTF ROI), evaluation.txt and figures
        (mtf_curves.png, mtf50_field.png, images.png, difference.png) into --out (default:
        a folder <result stem>_evaluation beside the result).

        Example: metasensor evaluate result/image.tif --truth cap/truth.tif --chart --out eval/
        """
        from metasensor.io.atomic import StagedFolder
        from metasensor.io.guard import guard
        from metasensor.metrics.evaluation import OUTPUT_FILES, evaluate_full, write_evaluation

        if out is None:
            out = result.parent / f"{result.stem}_evaluation"
        guard([result, truth], [out / n for n in OUTPUT_FILES], folders=[out])
        img = read_image(result, "result image")
        ref = read_image(truth, "truth image") if truth is not None else None
        rois = [parse_roi(r) for r in roi] if roi else None
        res, fm = evaluate_full(img, ref, chart=chart, rois=rois, pixel_pitch=pixel_pitch,
                                data_range=data_range, progress=True)
        res["inputs"] = {"result": str(result), "truth": None if truth is None else str(truth)}
        staged = StagedFolder(out, OUTPUT_FILES)  # the folder appears complete, or not at all
        written = write_evaluation(staged.path, res, fm, image=img, truth=ref)
        staged.commit()
        typer.echo((out / "evaluation.txt").read_text().rstrip())
        typer.echo(f"wrote {len(written)} files to {out}")
