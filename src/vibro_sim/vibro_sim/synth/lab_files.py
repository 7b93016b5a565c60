"""A synthetic recording as a lab's files: a Photron MRAW (+ .cih header) and an NI TDMS of the accelerometers.

``vibro synth --lab-files`` writes these instead of ``frames/`` and ``accel.csv``, and no rig.yaml: the
folder then holds what a lab's camera and DAQ give it, and ``vibro init`` sets the rig up from it as it
does for a lab (the truth file beside the folder names the ``accelerometers`` block rig.yaml needs for the
TDMS, :data:`LAB_ACCEL`).

The MRAW is streamed: :class:`MrawWriter` appends each frame to ``video.mraw`` as it is rendered (a
20,000-frame take of 160x480 px is 1.5 GB, never held in memory) and writes the header last, with
pyMRAW's own ``save_mraw`` (one frame into a scratch folder, its .cih kept): a synth interrupted while
writing frames leaves no header, so the half-written file is refused as a recording instead of being
read as a shorter one. The TDMS holds two waveform channels (``wf_increment``, ``wf_start_time``,
``wf_start_offset``, ``wf_samples``, ``unit_string``), written with npTDMS's ``TdmsWriter``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import BinaryIO

import numpy as np

from vibro_io.rig import AccelConfig

VIDEO_MRAW = "video.mraw"
VIDEO_CIH = "video.cih"
ACCEL_TDMS = "accel.tdms"
#: the rig.yaml ``accelerometers`` block for the TDMS synth writes (what a lab adds to init's rig.yaml)
LAB_ACCEL = AccelConfig(file=ACCEL_TDMS, group="accel", upper_channel="upper_plate", lower_channel="lower_plate")
#: the DAQ's wall-clock start written as the channels' wf_start_time (the camera file carries none)
DAQ_START = np.datetime64("2026-01-01T12:00:00.000000")
#: what a lab-file recording folder holds (what --overwrite may replace)
LAB_OUTPUTS = (VIDEO_MRAW, VIDEO_CIH, ACCEL_TDMS, "rig.yaml", "rig_preview.png")


class MrawWriter:
    """Streams frames into ``folder/video.mraw`` and writes ``folder/video.cih`` when all ``n_frames`` are in.

    Parameters
    ----------
    folder : Path
        The recording folder.
    n_frames : int
        The frames the header announces (``Total Frame``); :meth:`close` refuses fewer.
    fps : float
        The record rate (frames/s).
    shutter_s : float
        The exposure written as ``Shutter Speed(s)``.

    Notes
    -----
    8-bit frames only (uint8, ``Color Bit`` 8), rows as given, each frame's bytes in C order: the layout
    pyMRAW reads. Use as a context manager; leaving it by an exception removes the partial file.
    """

    def __init__(self, folder: Path, n_frames: int, fps: float, shutter_s: float) -> None:
        self.folder = Path(folder)
        self.n_frames = int(n_frames)
        self.fps = float(fps)
        self.shutter_s = float(shutter_s)
        self.count = 0
        self._first: np.ndarray | None = None
        self._fh: BinaryIO | None = None

    def __enter__(self) -> MrawWriter:
        self._fh = (self.folder / VIDEO_MRAW).open("wb")
        return self

    def write(self, image: np.ndarray) -> None:
        """Append one 8-bit grayscale frame (all frames of the same size)."""
        if image.dtype != np.uint8 or image.ndim != 2:
            raise ValueError(f"MRAW frames must be 2-D uint8, got {image.dtype} {image.shape}")
        if self._first is None:
            self._first = image.copy()
        elif image.shape != self._first.shape:
            raise ValueError(f"frame {self.count}: {image.shape} differs from frame 0's {self._first.shape}")
        assert self._fh is not None, "MrawWriter.write outside its with block"
        self._fh.write(np.ascontiguousarray(image).tobytes())
        self.count += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        assert self._fh is not None
        self._fh.close()
        if exc_type is not None:
            (self.folder / VIDEO_MRAW).unlink(missing_ok=True)
            return
        if self.count != self.n_frames or self._first is None:
            raise ValueError(f"{self.folder / VIDEO_MRAW}: {self.count} frames written, {self.n_frames} announced")
        self._write_header()

    def _write_header(self) -> None:
        """video.cih from pyMRAW.save_mraw (one frame into a scratch folder; its .mraw discarded)."""
        import pyMRAW

        info = {"Record Rate(fps)": f"{self.fps:g}", "Shutter Speed(s)": f"{self.shutter_s:.6f}",
                "Total Frame": str(self.n_frames), "Original Total Frame": str(self.n_frames), "Start Frame": "0",
                "EffectiveBit Depth": 8, "Comment Text": "vibro synth --lab-files"}
        scratch = Path(tempfile.mkdtemp(prefix=".cih_", dir=self.folder))
        try:
            _, cih = pyMRAW.save_mraw(self._first[None], str(scratch / VIDEO_MRAW), bit_depth=8, info_dict=info)
            os.replace(cih, self.folder / VIDEO_CIH)
        finally:
            shutil.rmtree(scratch, ignore_errors=True)


def write_accel_tdms(path: Path, t_daq_s: np.ndarray, upper_ms2: np.ndarray, lower_ms2: np.ndarray,
                     rate_hz: float) -> Path:
    """The two plates' accelerations (m/s^2) as waveform channels of :data:`LAB_ACCEL` in an NI TDMS file.

    Parameters
    ----------
    path : Path
        The TDMS file to write.
    t_daq_s : numpy.ndarray
        The samples' times on the DAQ clock (s), evenly spaced at ``1 / rate_hz``.
    upper_ms2, lower_ms2 : numpy.ndarray
        The upper and lower plate's samples (m/s^2).
    rate_hz : float
        The DAQ's sample rate (Hz).

    Returns
    -------
    Path
        ``path``.

    Notes
    -----
    Sample *i* is at ``wf_start_offset + i * wf_increment`` after ``wf_start_time``: the offset is the first
    sample's DAQ time (the same times accel.csv would hold), the start time :data:`DAQ_START`.
    """
    from nptdms import ChannelObject, GroupObject, TdmsWriter

    props = {"wf_increment": 1.0 / rate_hz, "wf_start_time": DAQ_START, "wf_start_offset": float(t_daq_s[0]),
             "wf_samples": int(upper_ms2.size), "unit_string": "m/s^2"}
    cfg = LAB_ACCEL
    with TdmsWriter(str(path)) as writer:
        writer.write_segment([GroupObject(cfg.group),
                              ChannelObject(cfg.group, cfg.upper_channel, np.asarray(upper_ms2, dtype=np.float64),
                                            properties=props),
                              ChannelObject(cfg.group, cfg.lower_channel, np.asarray(lower_ms2, dtype=np.float64),
                                            properties=props)])
    return path


def lab_files_truth(accel: bool) -> dict:
    """The truth file's ``lab_files`` section: the files written and the rig.yaml block for the TDMS."""
    out = {"video": VIDEO_CIH, "video_data": VIDEO_MRAW, "bit_depth": 8,
           "note": "no rig.yaml: run vibro init on the folder; with accelerometers, add the 'accelerometers' "
                   "block below to the rig.yaml it writes"}
    if accel:
        out["accel"] = ACCEL_TDMS
        out["accelerometers"] = LAB_ACCEL.to_dict()
        out["accel_time"] = ("sample i at wf_start_offset + i * wf_increment (wf_start_time: a nominal wall clock, "
                             "the camera file has none): the DAQ-clock times accel.csv's time_s would hold "
                             "(clock_convention)")
    return out
