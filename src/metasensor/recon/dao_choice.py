"""Whether a reconstruction estimates the aberration (DAO) and how: the ``"auto"`` default.

The paper's pipeline always measures the wavefront before it deconvolves (Wu et al. 2022,
Methods, "ISA with multisite DAO in wave optics"): the optics of a real capture are never known
well enough. ``"auto"`` follows it where nothing else says what the aberration is: without a
PSF bank, a Noll vector or a field map (a system calibration), every block runs wave-optics DAO,
and a block whose estimate is negligible (under :data:`NEGLIGIBLE_RMS` waves r.m.s., Noll 4-45)
keeps the aberration-free bank, so an aberration-free capture gets the plain ISA image. Whether
the estimate is negligible is decided by a probe: one DAO update on the ISA image of at most
:data:`PROBE_SAMPLES` x :data:`PROBE_SAMPLES` view samples of the block (the most detailed of its
centre and edges); only a probe above the threshold runs the full estimate, on the block's most
detailed sub-window of at most :data:`DAO_SAMPLES` x :data:`DAO_SAMPLES` view samples (a block
has one wavefront, and DAO's time and memory grow with the samples it reads). Where the
aberration is given, ``"auto"`` uses it as is (``"wave"`` with it starts DAO from it). Why the
threshold is what it is: docs/decisions.md ("the DAO default").
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DAO_CHOICES", "NEGLIGIBLE_RMS", "PROBE_SAMPLES", "DAO_SAMPLES", "DaoChoice",
           "choose_dao", "block_dao_options"]

#: what ``method`` / ``--dao`` accept ("none" is "isa": no aberration estimate)
DAO_CHOICES = ("auto", "none", "isa", "wave", "geometric")
#: waves r.m.s. (Noll 4-45) under which ``"auto"`` keeps a block's aberration-free bank
NEGLIGIBLE_RMS = 0.02
#: view samples per side of the sub-window on which a block's probe decides (larger windows:
#: :func:`metasensor.recon.probe.probe_window`); why: docs/decisions.md ("the cost of the
#: default reconstruction")
PROBE_SAMPLES = 160
#: view samples per side of the sub-window on which a block's DAO estimates its wavefront
#: (larger windows: :func:`metasensor.recon.probe.probe_window`); why: docs/decisions.md ("DAO
#: on a large block")
DAO_SAMPLES = 160


@dataclass(frozen=True)
class DaoChoice:
    """What :func:`choose_dao` decided.

    Attributes
    ----------
    method : str
        ``"isa"`` (no estimate), ``"wave"`` or ``"geometric"`` (DAO per block first).
    negligible : float
        Waves r.m.s. under which a block's DAO estimate is not applied (the block keeps its
        given, or the aberration-free, bank); 0: always applied.
    reason : str
        One line saying why, for the command line's output.
    """

    method: str
    negligible: float
    reason: str


def choose_dao(mode: str, *, aberration_given: bool, bank_given: bool,
               unavailable: str | None = None) -> DaoChoice:
    """The reconstruction method for ``mode`` (one of :data:`DAO_CHOICES`).

    Parameters
    ----------
    mode : str
        ``"auto"``: wave DAO per block unless the aberration (``aberration_given``: a Noll
        vector, a field map or a system calibration) or a complete PSF bank (``bank_given``) is
        given; blocks with a negligible estimate keep the aberration-free bank. ``"none"`` /
        ``"isa"``: no estimate (the fast path). ``"wave"`` / ``"geometric"``: DAO in every
        block, its estimate always applied.
    aberration_given, bank_given : bool
        What the caller supplied besides the views.
    unavailable : str or None
        Why DAO cannot run on this system (:func:`metasensor.dao.estimate.dao_unavailable`);
        ``"auto"`` then reconstructs without an estimate and says why.

    Returns
    -------
    DaoChoice
    """
    if mode not in DAO_CHOICES:
        raise ValueError(f"DAO mode must be one of {', '.join(DAO_CHOICES)}, got {mode!r}")
    if mode in ("none", "isa"):
        return DaoChoice("isa", 0.0, "no aberration estimate (--dao none)")
    if mode != "auto":
        return DaoChoice(mode, 0.0, f"{mode} DAO in every block")
    if bank_given:
        return DaoChoice("isa", 0.0, "the given PSF bank is used as is (no aberration estimate)")
    if aberration_given:
        return DaoChoice("isa", 0.0, "the given aberration is used as is (--dao wave estimates "
                                     "it per block, starting from it)")
    if unavailable:
        return DaoChoice("isa", 0.0, f"not estimated: {unavailable}")
    return DaoChoice("wave", NEGLIGIBLE_RMS,
                     f"no aberration given: wave DAO estimates it per block; a block under "
                     f"{NEGLIGIBLE_RMS:g} λ r.m.s. keeps the aberration-free bank "
                     "(--dao none: skip the estimate)")


def block_dao_options(method: str, cfg, dao, view_mask, stacklevel: int = 2):
    """The :class:`metasensor.dao.options.DaoOptions` every block's DAO runs with (None for
    ``method="isa"``): ``dao`` (default ``DaoOptions()``) with ``method`` and its modes resolved
    once for the reconstruction's views ``view_mask``
    (:func:`metasensor.dao.estimate.dao_modes`: where not given, the leading Noll set those
    views determine, warned once when fewer than 4–45; given modes they cannot determine, and
    too few views, are refused with a ValueError before any block runs)."""
    if method == "isa":
        return None
    from dataclasses import replace

    from metasensor.dao.estimate import DaoOptions, dao_modes

    base = dao or DaoOptions()
    modes = dao_modes(cfg, view_mask, base.modes, stacklevel=stacklevel + 1)
    return replace(base, method=method, modes=modes)
