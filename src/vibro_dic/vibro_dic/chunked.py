"""Chunked DIC of one long recording on Dask workers, joined in frame order: the same dic.csv as one process.

Design: DIC measures every frame against the reference (frame 0); the only state carried from frame to
frame is the motion prediction of the integer search, and the tracker restarts it at every multiple of
:data:`~vibro_dic.tracker.RESEED_EVERY_FRAMES` frame indices, in one process too (module doc of
:mod:`vibro_dic.tracker`, step 6). A chunk here is one such segment, so the segment boundaries, and with
them the rows, do not depend on the number of workers. Each task gets the recording as the planning process
opened it (pickled; its frame files are read by path, so a remote cluster's workers must see that path),
builds its own tracker on the reference and tracks its segment (:func:`track_slots`). The rows come back in
frame order through the same checks as a single pass (:func:`emit_rows`: the unreadable-fraction guard and
the log line of each unreadable frame, in this process), and an exception of a chunk (e.g. an unreadable
reference) is raised when the join reaches that chunk, as one process raises it there.
"""

from __future__ import annotations

from typing import Iterator

from vibro_io.dictrack import FrameTrack

from .tracker import RESEED_EVERY_FRAMES, SlotNote, emit_rows, track_slots


def segment_starts(first_index: int, n_slots: int, reseed_every: int = RESEED_EVERY_FRAMES) -> list[int]:
    """Slot positions where a tracking segment starts: 0 and every slot whose frame index
    (``first_index`` + position) is a multiple of ``reseed_every``."""
    first_boundary = -(-first_index // reseed_every) * reseed_every  # ceil to a multiple
    starts = [0] + [k - first_index for k in range(first_boundary, first_index + n_slots, reseed_every)]
    return sorted(set(starts))


def track_chunk(recording, start: int, stop: int | None, method: str,
                tracker_kwargs: dict) -> list[tuple[FrameTrack, SlotNote]]:
    """One Dask task: the noted rows of slots ``start`` .. ``stop`` - 1 of ``recording`` (the Recording as
    the planning process opened it, pickled: its frame files are read here, nothing is re-validated)."""
    return list(track_slots(recording, start, stop, method=method, **tracker_kwargs))


def track_recording_chunked(recording, client, *, method: str = "icgn", progress: bool = False,
                            **tracker_kwargs) -> Iterator[FrameTrack]:
    """The rows of :func:`vibro_dic.tracker.track_recording` (identical), tracked one segment per Dask task
    on ``client`` (a ``distributed.Client``) and yielded in frame order."""
    from tqdm import tqdm

    frames = recording.frames
    reseed = tracker_kwargs.get("reseed_every", RESEED_EVERY_FRAMES)
    starts = segment_starts(frames.first_index, len(frames), reseed)
    bounds = list(zip(starts, starts[1:] + [None]))  # the last chunk reads to the end (a video may run longer)
    [shared] = client.scatter([recording], broadcast=False, hash=False)
    futures = [client.submit(track_chunk, shared, a, b, method, dict(tracker_kwargs), pure=False)
               for a, b in bounds]
    bar = tqdm(total=len(frames), unit="frame", disable=not progress, desc="track", leave=False)

    def noted_rows():
        for future in futures:
            yield from future.result()
            future.release()

    try:
        yield from emit_rows(noted_rows(), frames.unreadable_guard(), bar)
    finally:
        bar.close()
        client.cancel([f for f in futures if not f.done()])


def track_rows(recording, *, workers: int | None = None, scheduler: str | None = None, client=None,
               method: str = "icgn", progress: bool = False, **tracker_kwargs) -> Iterator[FrameTrack]:
    """The rows of ``recording``: in this process (``workers`` None or 1, no ``scheduler``, no ``client``),
    else in chunks on ``client``, on the scheduler at ``scheduler`` or on a new local cluster of ``workers``
    processes (open while the rows are read). The same rows either way (module doc)."""
    from .cluster import check_workers, dask_client
    from .tracker import track_recording

    check_workers(workers)
    if client is not None:
        yield from track_recording_chunked(recording, client, method=method, progress=progress, **tracker_kwargs)
    elif scheduler is not None or (workers is not None and workers > 1):
        with dask_client(workers, scheduler) as new_client:
            yield from track_recording_chunked(recording, new_client, method=method, progress=progress,
                                               **tracker_kwargs)
    else:
        yield from track_recording(recording, method=method, progress=progress, **tracker_kwargs)
