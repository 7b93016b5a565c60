"""The time base of a camera file's saved frames, from its own clock where it has one.

A high-speed camera records at its frame rate; what lands in the file may be every ``step``-th
recorded frame (Photron "Save Step" / ``skipFrame``, Phantom files saved with a step) and, in a
Phantom CINE, every saved image carries its own time stamp (the tagged "time only" block, type
1002: one TIME64 per image, seconds since 1970 + fractions / 2**32). The time base is, by
precedence:

1. **time stamps** (CINE): the saved images lie on a grid of spacing ``dt`` (the median spacing of
   consecutive images, per slot across a dropped one; origin the median offset); image k sits in slot
   ``round((t_k - t_first) / dt)``: consecutive slots for a regular file, a gap where the camera
   dropped images (reported like missing frame files). A stamp further than
   :data:`MAX_STAMP_RESIDUAL` of a spacing from the grid, or that would put the image out of
   order, is corrupt: that image is delivered as unreadable (its time is unknown), never placed
   by guess. Disagreement with the header's rate is reported, with the ratio.
2. **header and save step** (Photron): spacing ``step / record rate``, when the header's recorded
   frame count can hold the saved frames that far apart; when it cannot, the header contradicts
   itself and no rate is chosen: rig.yaml's ``camera.fps`` must say which (:class:`TimeBase`
   ``fps`` None, ``candidates_fps`` listing both readings).
3. **header** rate alone.

Times are seconds; rates frames per second of the *saved* frames unless named ``record_fps``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: A stamp further than this fraction of the spacing from the grid is corrupt (its image unreadable).
MAX_STAMP_RESIDUAL = 0.25
#: More corrupt stamps than this share refuse the file (its clock is not a clock).
MAX_CORRUPT_STAMP_SHARE = 0.05
#: Relative difference between two readings of the rate below which they are said to agree.
RATE_AGREEMENT = 1e-3


@dataclass(frozen=True, kw_only=True)
class TimeBase:
    """Where the saved frames lie in time.

    ``fps``: rate of the saved frames (frames/s), None when the header contradicts itself;
    ``source``: "time stamps", "header save step" or "header"; ``record_fps``: the header's
    recording rate; ``step``: the header's saved-frame step (1: every frame); ``slots``: slot
    (0-based, on the ``fps`` grid) of each file frame, -1 for a corrupt stamp, None when the file
    has no stamps (frame k in slot k); ``t0_s``: time of slot 0 relative to the trigger (s) or None;
    ``start_unix_s``: wall-clock time of slot 0 (Unix s) or None; ``notes``: disagreements and
    repairs, one sentence each; ``candidates_fps``: the readings a user must choose between when
    ``fps`` is None; ``jitter_s``: largest |stamp - grid| of the valid stamps (s), None without stamps.
    """

    fps: float | None
    source: str
    record_fps: float
    step: int = 1
    slots: np.ndarray | None = None
    t0_s: float | None = None
    start_unix_s: float | None = None
    notes: tuple[str, ...] = ()
    candidates_fps: tuple[float, ...] = ()
    jitter_s: float | None = None
    corrupt: tuple[int, ...] = ()

    @property
    def readings_fps(self) -> tuple[float, ...]:
        """The rates the file allows: its one rate, or the candidates of a contradictory header."""
        return self.candidates_fps if self.fps is None else (self.fps,)

    def names_same_spacing(self, fps: float, n_frames: int) -> bool:
        """Whether a user's rate ``fps`` names one of :attr:`readings_fps` (within :func:`fps_tolerance`)."""
        tolerance = fps_tolerance(self, n_frames)
        return any(abs(fps - r) <= tolerance * r for r in self.readings_fps)

    @property
    def n_slots(self) -> int | None:
        """Frame slots from the first to the last valid image (dropped ones included); None without stamps."""
        if self.slots is None:
            return None
        valid = self.slots[self.slots >= 0]
        return int(valid.max()) + 1 if valid.size else 0

    @property
    def dropped_slots(self) -> int:
        """Slots with no image (images the camera's clock says were not saved)."""
        if self.slots is None:
            return 0
        return int(self.n_slots or 0) - int((self.slots >= 0).sum())


def from_header_step(record_fps: float, step: int, n_saved: int, n_recorded: int | None, start_frame: int | None,
                     name: str) -> TimeBase:
    """The time base a Photron header gives: record rate, saved-frame step, recorded frame count.

    Parameters
    ----------
    record_fps : float
        The record rate (frames/s) in the header.
    step : int
        Saved-frame step: every ``step``-th recorded frame was saved.
    n_saved : int
        Frames in the file.
    n_recorded : int or None
        Frames the camera recorded (None: not in the header).
    start_frame : int or None
        The recorded frame number of the first saved frame (None: not in the header).
    name : str
        The file, named in the time base's description.

    Returns
    -------
    TimeBase
        ``fps`` is the saved frames' rate (frames/s), None when the header contradicts itself.

    Notes
    -----
    ``step`` > 1 is trusted when ``(n_saved - 1) * step < n_recorded`` (the recorded take can hold the
    saved frames that far apart); otherwise the header contradicts itself and ``fps`` is None.
    """
    t0 = None if start_frame is None else start_frame / record_fps
    if step <= 1:
        return TimeBase(fps=record_fps, source="header", record_fps=record_fps, t0_s=t0)
    saved_fps = record_fps / step
    span = (n_saved - 1) * step + 1
    if n_recorded is not None and span > n_recorded:
        note = (f"{name}: the header records {record_fps:g} frames/s and a saved-frame step of {step}, but "
                f"{n_saved} frames {step} apart span {span} recorded frames and the take holds {n_recorded}: "
                f"the header contradicts itself; set camera.fps in rig.yaml to {record_fps:g} if the saved "
                f"frames are consecutive or to {saved_fps:g} if every {step}th frame was saved")
        return TimeBase(fps=None, source="header (contradictory)", record_fps=record_fps, step=step, t0_s=t0,
                        notes=(note,), candidates_fps=(record_fps, saved_fps))
    note = (f"{name}: every {step}th recorded frame was saved (header step {step} at {record_fps:g} frames/s): "
            f"the saved frames are {step / record_fps:.6g} s apart ({saved_fps:g} frames/s)")
    return TimeBase(fps=saved_fps, source="header save step", record_fps=record_fps, step=step, t0_s=t0,
                    notes=(note,))


def from_stamps(stamps_s: np.ndarray, origin_unix_s: float, record_fps: float, trigger_s: float | None,
                name: str) -> TimeBase:
    """The time base of a file whose images carry their own time stamps (one per image, file order).

    Parameters
    ----------
    stamps_s : numpy.ndarray
        Each image's time stamp, s after ``origin_unix_s``.
    origin_unix_s : float
        A whole Unix second near the stamps (s since the Unix epoch): relative values keep the stamps'
        resolution, which an absolute Unix time in float64 loses.
    record_fps : float
        The rate (frames/s) the header states.
    trigger_s : float or None
        The trigger time, s after ``origin_unix_s`` (None: unknown).
    name : str
        The file, named in the time base's description.

    Returns
    -------
    TimeBase
        The rate measured from the stamps (frames/s) and each image's time.

    Raises
    ------
    ValueError
        The stamps do not form a clock (the caller names the file): fewer than 2, no positive spacing, more
        than :data:`MAX_CORRUPT_STAMP_SHARE` corrupt, or valid ones out of order.
    """
    t = np.asarray(stamps_s, dtype=np.float64)
    n = t.size
    if n < 2:
        raise ValueError("fewer than 2 image time stamps")
    steps = np.diff(t)
    positive = steps[steps > 0]
    if positive.size == 0:
        raise ValueError("the image time stamps never increase")
    dt = float(np.median(positive))
    anchor = int(np.argsort(t)[n // 2])  # the median stamp: robust to a garbage stamp at either end
    rel = (t - t[anchor]) / dt
    slot = np.round(rel).astype(np.int64)
    valid = (np.abs(rel - slot) <= MAX_STAMP_RESIDUAL) & (np.abs(slot - (np.arange(n) - anchor)) <= n)
    if valid.sum() < 2:
        raise ValueError("no two image time stamps lie on one clock")
    k = slot[valid]
    if np.any(np.diff(k) <= 0):
        bad = int(np.flatnonzero(valid)[np.flatnonzero(np.diff(k) <= 0)[0] + 1])
        raise ValueError(f"image {bad}'s time stamp is not after the previous image's: the images are out of order")
    corrupt = np.flatnonzero(~valid)
    if corrupt.size > MAX_CORRUPT_STAMP_SHARE * n and corrupt.size > 1:
        raise ValueError(f"{corrupt.size} of {n} image time stamps lie off the camera's clock "
                         f"(more than {MAX_CORRUPT_STAMP_SHARE:.0%}), first image {int(corrupt[0])}")
    k0 = int(k.min())
    slots = np.where(valid, slot - k0, -1)
    tv, kv = t[valid], slots[valid]
    dt = float(np.median(np.diff(tv) / np.diff(kv)))  # median spacing, per slot across a dropped image
    t_slot0 = float(np.median(tv - kv * dt))
    jitter = float(np.max(np.abs(tv - (t_slot0 + kv * dt))))
    fps = 1.0 / dt
    notes = []
    ratio = record_fps / fps
    if abs(ratio - 1.0) > RATE_AGREEMENT:
        step = round(ratio)
        why = (f"every {step}th recorded frame was saved" if step >= 2 and abs(ratio - step) < 0.01 * step
               else "the header's rate is not the saved images' spacing")
        notes.append(f"{name}: the header says {record_fps:g} frames/s but the images' own time stamps are "
                     f"{dt * 1e6:.4g} us apart ({fps:.6g} images/s, {ratio:.4g} x fewer): {why}; the time stamps "
                     "are the time base")
    for i in corrupt:
        j = int(np.flatnonzero(valid)[np.argmin(np.abs(np.flatnonzero(valid) - i))])  # nearest valid image
        expected = t_slot0 + (slots[j] + (int(i) - j)) * dt
        notes.append(f"{name}: image {int(i)}'s time stamp ({origin_unix_s + t[i]:.6f} Unix s) lies "
                     f"{t[i] - expected:+.6g} s from "
                     "where the camera's clock puts it: its time is unknown and it is treated as unreadable")
    dropped = int(slots.max()) + 1 - int(valid.sum())
    if dropped:
        notes.append(f"{name}: the time stamps leave {dropped} slot(s) empty: the camera dropped images "
                     "(reported like missing frame files)")
    t0 = None if trigger_s is None else t_slot0 - trigger_s
    return TimeBase(fps=fps, source="time stamps", record_fps=record_fps, slots=slots, t0_s=t0,
                    start_unix_s=origin_unix_s + t_slot0, notes=tuple(notes), jitter_s=jitter,
                    corrupt=tuple(int(i) for i in corrupt))


def fps_tolerance(base: TimeBase, n_frames: int) -> float:
    """Relative difference from ``base.fps`` within which a user's camera.fps names the same spacing.

    Parameters
    ----------
    base : TimeBase
        The file's time base.
    n_frames : int
        Frames in the take.

    Returns
    -------
    float
        The tolerance, relative (dimensionless).

    Notes
    -----
    Header-derived rates are exact numbers: 1e-6. A rate measured from stamps is known to the stamps'
    jitter; a user value is accepted when it moves the last frame by less than 0.1 frame.
    """
    if base.source != "time stamps":
        return 1e-6
    return max(1e-6, 0.1 / max(n_frames, 1))
