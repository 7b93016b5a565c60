"""Sub-pixel digital image correlation (ZNCC + IC-GN) of ball and structure.

Public API: :func:`vibro_dic.mesh.mesh_points`, :class:`vibro_dic.tracker.DicTracker`,
:func:`vibro_dic.tracker.track_recording`, :func:`vibro_dic.noise.noise_study`,
:mod:`vibro_dic.speckle` (synthetic speckle with exact sub-pixel shifts). Imports without rclpy.

The tracker's names are loaded when first asked for (``from vibro_dic import DicTracker`` works as before): the
package's ``__init__`` runs before any of its modules, and the frame source node (``vibro_dic.frame_source_node``,
started by every graph run) and the ``vibro`` commands that track nothing need neither the tracker nor its numba
kernels (~0.3-0.4 s of CPU at each start).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .mesh import mesh_points

if TYPE_CHECKING:
    from .tracker import DicTracker, MeshResult, track_recording

__all__ = ["DicTracker", "MeshResult", "mesh_points", "track_recording"]

#: public name -> the module that defines it (numba and scipy come with it)
_LAZY = {"DicTracker": "tracker", "MeshResult": "tracker", "track_recording": "tracker"}


def __getattr__(name: str):
    """The public names, imported from their module on first use (PEP 562)."""
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
