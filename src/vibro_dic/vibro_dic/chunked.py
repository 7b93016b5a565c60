"""Chunked DIC of one long recording on Dask workers, joined in frame order: the same dic.csv as one process.

Design: DIC measures every frame against the reference (frame 0); the only state carried from frame to
frame is the motion prediction of the integer search, and the tracker restarts it at every multiple of
:data:`~vibro_dic.tracker.RESEED_EVERY_FRAMES` frame indices, in one process too (module doc of
:mod:`vibro_dic.tracker`, step 6). A chunk here is one such segment, so the segment boundaries, and with
them the rows, do not depend on the number of workers. Each task gets the recording as the planning process
opened it (pickled; its frame files are read by path, so a remote cluster's workers must see that path),
builds its own tracker on the reference and tracks its segment (:func:`track_slots`). The texture check
(:func:`~vibro_dic.tracker.reference_texture`: its warnings, its refusal, the unusable subsets) runs once, in
this process, before any chunk (and before a local cluster is started); every chunk's tracker leaves out the
subsets it found unusable. The rows come back in frame order through the same checks as a single pass
(:func:`emit_rows`: the unreadable-fraction guard, the log line of each unreadable frame and the correlation
quality (:class:`~vibro_dic.quality.TrackQuality`) fed frame by frame, in this process), and an exception
of a chunk (e.g. an unreadable reference) is raised when the join reaches that chunk, as one process raises
it there.
"""

from __future__ import annotations

from typing import Iterator

from vibro_io.dictrack import FrameTrack

from .cluster import check_workers, dask_client
from .quality import TrackQuality
from .texture import DEFAULT_MAX_SUBSET_SIGMA_PX, TextureReport
from .tracker import RESEED_EVERY_FRAMES, SlotNote, emit_rows, reference_texture, track_recording, track_slots


def segment_starts(first_index: int, n_slots: int, reseed_every: int = RESEED_EVERY_FRAMES) -> list[int]:
    """Slot positions where a tracking segment starts: 0 and every slot whose frame index
    (``first_index`` + position) is a multiple of ``reseed_every``."""
    first_boundary = -(-first_index // reseed_every) * reseed_every  # ceil to a multiple
    starts = [0] + [k - first_index for k in range(first_boundary, first_index + n_slots, reseed_every)]
    return sorted(set(starts))


def track_chunk(recording, start: int, stop: int | None, method: str, texture: TextureReport,
                tracker_kwargs: dict) -> list[tuple[FrameTrack, SlotNote]]:
    """One Dask task: the noted rows of slots ``start`` .. ``stop`` - 1 of ``recording`` (the Recording as
    the planning process opened it, pickled: its frame files are read here, nothing is re-validated),
    with the unusable subsets of ``texture`` (the planning process's texture check) left out."""
    return list(track_slots(recording, start, stop, texture=texture, method=method, **tracker_kwargs))


def track_recording_chunked(recording, client, *, method: str = "icgn", progress: bool = False,
                            quality: TrackQuality | None = None,
                            max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX,
                            **tracker_kwargs) -> Iterator[FrameTrack]:
    """The rows of :func:`vibro_dic.tracker.track_recording` (identical, and the same ``quality``), tracked
    one segment per Dask task on ``client`` (a ``distributed.Client``) and yielded in frame order."""
    texture = _reference_texture(recording, quality, max_subset_sigma_px, tracker_kwargs)
    yield from _join_chunks(recording, client, texture, method, progress, quality, tracker_kwargs)


def _reference_texture(recording, quality, max_subset_sigma_px: float, tracker_kwargs: dict) -> TextureReport:
    """The texture check of the pass, in this process, as one process does it (:func:`reference_texture`)."""
    return reference_texture(recording, max_subset_sigma_px=max_subset_sigma_px,
                             min_valid_fraction=tracker_kwargs.get("min_valid_fraction", 0.5), quality=quality)


def _join_chunks(recording, client, texture: TextureReport, method: str, progress: bool,
                 quality: TrackQuality | None, tracker_kwargs: dict) -> Iterator[FrameTrack]:
    from tqdm import tqdm

    frames = recording.frames
    reseed = tracker_kwargs.get("reseed_every", RESEED_EVERY_FRAMES)
    starts = segment_starts(frames.first_index, len(frames), reseed)
    bounds = list(zip(starts, starts[1:] + [None]))  # the last chunk reads to the end (a video may run longer)
    shared_recording, shared_texture = client.scatter([recording, texture], broadcast=False, hash=False)
    futures = [client.submit(track_chunk, shared_recording, a, b, method, shared_texture, dict(tracker_kwargs),
                             pure=False) for a, b in bounds]
    bar = tqdm(total=len(frames), unit="frame", disable=not progress, desc="track", leave=False)

    def noted_rows():
        for future in futures:
            yield from future.result()
            future.release()

    try:
        yield from emit_rows(noted_rows(), frames.unreadable_guard(), bar, quality)
    finally:
        bar.close()
        client.cancel([f for f in futures if not f.done()])


def track_rows(recording, *, workers: int | None = None, scheduler: str | None = None, client=None,
               method: str = "icgn", progress: bool = False, quality: TrackQuality | None = None,
               max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX, **tracker_kwargs) -> Iterator[FrameTrack]:
    """The DIC rows of a recording, one per frame, in frame order: the same rows and ``quality`` in this process
    or in chunks on Dask workers (module doc).

    Parameters
    ----------
    recording : Recording
        The opened recording (:func:`vibro_io.recording.open_recording`).
    workers : int, optional
        None or 1: in this process; more: on a new local cluster of that many processes (open while the rows
        are read; started after the texture check passed).
    scheduler : str, optional
        The address of a running Dask scheduler to track on.
    client : distributed.Client, optional
        A Dask client to track on.
    method : str
        The DIC sub-pixel method: ``"icgn"`` or ``"parabolic"`` (:mod:`vibro_dic.tracker`).
    progress : bool
        A progress bar on stderr.
    quality : TrackQuality, optional
        Filled with the track's quality counters (lost subsets and frames, and why).
    max_subset_sigma_px : float
        The texture check's limit on a subset's predicted displacement std (px).
    **tracker_kwargs
        Passed on to :class:`vibro_dic.tracker.DicTracker`.

    Yields
    ------
    FrameTrack
        Each frame slot's time (s), ball and structure displacement (mm), valid mesh points and ZNCC, and
        whether the frame was lost.
    """
    check_workers(workers)
    if client is None and scheduler is None and (workers is None or workers <= 1):
        yield from track_recording(recording, method=method, progress=progress, quality=quality,
                                   max_subset_sigma_px=max_subset_sigma_px, **tracker_kwargs)
        return
    texture = _reference_texture(recording, quality, max_subset_sigma_px, tracker_kwargs)
    if client is not None:
        yield from _join_chunks(recording, client, texture, method, progress, quality, tracker_kwargs)
    else:
        with dask_client(workers, scheduler) as new_client:
            yield from _join_chunks(recording, new_client, texture, method, progress, quality, tracker_kwargs)
