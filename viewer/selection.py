"""Selecting and deleting Gaussians in the viewer (floater clean-up): what a screen rectangle selects, the
markers that show a selection, and the edit state with its undo history.

A rectangle selects the Gaussians whose centre *at the displayed time* projects into it, through every depth, among
those the renderer draws at that time (`sorting.depth_order`'s culls: faded out, below 1/255 opacity, behind the
near plane, off screen). A Gaussian that shows only at other times is therefore never caught by a rectangle drawn
now, which is what cleaning a 4D model needs: a floater that flickers in at t = 0.3 is selected at t = 0.3 without
touching the object that passes the same spot at t = 0.7.

`Edits` holds the user's deletions and selection as masks over the *loaded* model's Gaussians, so that they survive
crop-box changes (the renderer shows a subset; `shown_index` maps its indices back).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from splatreel.cameras import Camera

from .skinning import posed
from .sorting import SortResult
from .splats import SplatArrays

#: How many deletions Undo can take back.
UNDO_LEVELS = 32
#: Selection markers drawn at most (evenly spaced through the selection beyond): lines are cheap, not free.
MAX_MARKERS = 20_000
#: Modes of `Edits.select`.
SELECT_MODES = ("add", "remove", "replace")


def normalise_rect(x0: float, y0: float, x1: float, y1: float) -> tuple[float, float, float, float]:
    """A rectangle (left, top, right, bottom) from any two opposite corners (pixels, y down)."""
    return min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)


def in_rect(order: SortResult, rect: tuple[float, float, float, float]) -> np.ndarray:
    """Indices (into the sorted model, ascending) of the Gaussians of `order` whose projected centre lies in `rect`
    (left, top, right, bottom in the sorted camera's pixels, y down; left/top edges inclusive). `order` is a
    `SortResult` of the camera and time the rectangle was drawn at: its boxes hold each drawn Gaussian's centre."""
    left, top, right, bottom = normalise_rect(*rect)
    u, v = order.boxes[:, 0], order.boxes[:, 1]
    inside = (u >= left) & (u < right) & (v >= top) & (v < bottom)
    return np.sort(order.order[inside].astype(np.int64))


def centres_at(splats: SplatArrays, t: float, indices: np.ndarray) -> np.ndarray:
    """``[M, 3]`` centres at time `t` of Gaussians `indices` of `splats` (the conditional mean, moving in t with its
    velocity and acceleration; a skinned model's carried by its nodes, `skinning.posed`; a keyframed slice has no
    motion and stays where it was sliced)."""
    chosen = posed(splats.select(indices), t)
    m = chosen.mean_t
    dt = t - m[:, 3:4].astype(np.float64)
    return m[:, :3].astype(np.float64) + (chosen.motion[:, :3] + 0.5 * chosen.accel[:, :3] * dt) * dt


def marker_segments(points: np.ndarray, camera: Camera, pixels: float = 4.0) -> np.ndarray:
    """``[3M, 2, 3]`` segments: a 3-axis cross `pixels` px across (half-size at each point's depth) at each of
    ``[M, 3]`` `points` in front of `camera`; points behind it are left out. At most `MAX_MARKERS` crosses, evenly
    spaced through `points`."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) > MAX_MARKERS:
        pts = pts[np.linspace(0, len(pts) - 1, MAX_MARKERS).astype(np.int64)]
    w2c = np.asarray(camera.w2c, np.float64)
    z = pts @ w2c[2, :3] + w2c[2, 3]
    pts, z = pts[z > 0], z[z > 0]
    half = 0.5 * pixels * z / camera.fy
    segs = np.empty((len(pts), 3, 2, 3))
    for axis in range(3):
        offset = np.zeros((len(pts), 3))
        offset[:, axis] = half
        segs[:, axis, 0] = pts - offset
        segs[:, axis, 1] = pts + offset
    return segs.reshape(-1, 2, 3)


@dataclass
class Edits:
    """Deleted and selected Gaussians of a model of `len(deleted)` Gaussians, and the deletions Undo restores.

    Attributes:
        deleted, selected: ``[N]`` bool masks over the loaded model; a deleted Gaussian is never selected.
        history: earlier `deleted` masks, the newest last (at most `UNDO_LEVELS`).
        revision: counts the changes of either mask (what is derived from them is remade when it moves on).
    """

    deleted: np.ndarray
    selected: np.ndarray
    history: list = field(default_factory=list)
    revision: int = 0
    #: (revision, deleted count, selected count): the panel shows both every frame; a sum of a 1M mask is ~1 ms
    _counts: tuple = field(default=(-1, 0, 0), repr=False)

    @classmethod
    def of(cls, n: int) -> "Edits":
        return cls(np.zeros(n, bool), np.zeros(n, bool))

    def _counted(self) -> tuple:
        if self._counts[0] != self.revision:
            self._counts = (self.revision, int(self.deleted.sum()), int(self.selected.sum()))
        return self._counts

    @property
    def num_deleted(self) -> int:
        return self._counted()[1]

    @property
    def num_selected(self) -> int:
        return self._counted()[2]

    def select(self, indices: np.ndarray, mode: str = "add") -> int:
        """Add `indices` (of the loaded model) to the selection, remove them from it, or make them the selection
        (`SELECT_MODES`); deleted ones are skipped. Returns how many are selected now."""
        if mode not in SELECT_MODES:
            raise ValueError(f"unknown selection mode {mode!r}")
        idx = np.asarray(indices, np.int64)
        if mode == "replace":
            self.selected[:] = False
        self.selected[idx] = mode != "remove"
        self.selected &= ~self.deleted
        self.revision += 1
        return self.num_selected

    def clear_selection(self) -> None:
        self.selected[:] = False
        self.revision += 1

    def invert_selection(self, among: np.ndarray | None = None) -> int:
        """Select every Gaussian that is neither selected nor deleted (and unselect the others); with `among` (a
        ``[N]`` bool mask, e.g. what the window shows), only those: the others stay unselected."""
        self.selected = ~self.selected & ~self.deleted
        if among is not None:
            self.selected &= among
        self.revision += 1
        return self.num_selected

    def delete(self, indices: np.ndarray) -> int:
        """Delete Gaussians `indices` (one Undo step; the rest of the selection stays); returns how many were not
        deleted yet."""
        fresh = np.zeros_like(self.deleted)
        fresh[np.asarray(indices, np.int64)] = True
        fresh &= ~self.deleted
        count = int(fresh.sum())
        if count:
            self._remember()
            self.deleted |= fresh
            self.selected &= ~fresh
        return count

    def delete_selected(self) -> int:
        """Delete the selection (one Undo step); returns how many were deleted."""
        return self.delete(np.flatnonzero(self.selected))

    def undo(self) -> bool:
        """Restore the Gaussians of the last deletion (they come back unselected). False when there is none."""
        if not self.history:
            return False
        self.deleted = self.history.pop()
        self.selected &= ~self.deleted  # a Gaussian deleted again cannot stay selected
        self.revision += 1
        return True

    def restore_all(self) -> int:
        """Bring back every deleted Gaussian (one Undo step); returns how many."""
        count = self.num_deleted
        if count:
            self._remember()
            self.deleted = np.zeros_like(self.deleted)
        return count

    def _remember(self) -> None:
        """Before a change of `deleted`: keep it for Undo."""
        self.history.append(self.deleted.copy())
        del self.history[:-UNDO_LEVELS]
        self.revision += 1
