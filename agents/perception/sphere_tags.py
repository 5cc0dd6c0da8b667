"""Reading the tags printed on a node sphere through a model of the sphere (when the camera is known).

OpenCV's AprilTag detector looks for flat quadrilaterals; on a small sphere (a 20 px node at 2 m
with 8 stickers around the equator has 1.5-2.5 px per tag cell) the printed tag is curved and too
small for its quad finder. With the camera model (intrinsics ``K`` and the camera's rotation in the
observer's horizontal root frame, both in ``decentral.log/1``) and the node radius, the sphere's
centre follows from its eq. (1) circle, and the only unknown of the print's image is the node's yaw
(node frames are horizontal: z up). For every yaw on a grid and every sticker of the layout facing
the camera, the 8 x 8 cell centres of the print are projected into the image and sampled; the 6 x 6
data cells are matched against every code of the family (normalised correlation), and the best
hypothesis is accepted when its hamming distance and decision margin (as in
:mod:`agents.perception.apriltag`) pass. Copies of one tag on several sides make the node's yaw
ambiguous by the angle between stickers; the id is not.

The sticker layout is part of the robot model: :class:`StickerLayout` describes where the copies
sit (unit axes in the node frame, the tag's up direction, angular half-size; cells span
``2 half_angle`` in the tangent angles ``atan2(n . right, n . axis)`` and ``atan2(n . up, n . axis)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import cv2
import numpy as np

from agents.perception.apriltag import FAMILIES
from agents.perception.types import Circle

__all__ = ["StickerLayout", "SphereTagConfig", "SphereTagRead", "SphereTagReader", "SphereTagIdentifier"]


@dataclass(frozen=True)
class StickerLayout:
    """Tag copies on a node sphere (node frame): ``axes``, ``up`` (S, 3) unit, ``half_angle`` rad.

    ``right`` is ``up x axis`` (the print is not mirrored seen from outside).
    """

    axes: np.ndarray
    up: np.ndarray
    half_angle: float

    @property
    def right(self) -> np.ndarray:
        return np.cross(self.up, self.axes)

    @classmethod
    def around(cls, n_equator: int = 8, half_angle: float = 0.33, top: bool = True) -> "StickerLayout":
        """``n_equator`` upright stickers evenly around the equator (the first facing +x), one on top."""
        phi = 2 * np.pi * np.arange(n_equator) / n_equator
        axes = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n_equator)])
        up = np.tile([0.0, 0.0, 1.0], (n_equator, 1))
        if top:
            axes = np.vstack([axes, [0.0, 0.0, 1.0]])
            up = np.vstack([up, [1.0, 0.0, 0.0]])
        if n_equator and half_angle >= np.pi / n_equator:
            raise ValueError("stickers around the equator would overlap: half_angle must be < pi / n_equator")
        return cls(axes, up, float(half_angle))


@dataclass(frozen=True)
class SphereTagConfig:
    """Parameters of :class:`SphereTagReader`.

    Attributes
    ----------
    layout : StickerLayout
        Where the tag copies sit on a node.
    family : str
        Tag family.
    yaw_steps : int
        Yaw hypotheses over a full turn. With the default layout 45 (8 deg steps) samples every
        equator sticker's azimuth at 1 deg: the stickers sit 45 deg apart and 45 = 5 mod 8, 5 coprime
        to 8, so the 45 x 8 (yaw, sticker) pairs hit every whole degree once (180 steps read exactly
        the same nodes on rendered table1 frames at four times the cost). Choose it likewise for
        another layout.
    min_facing : float
        A sticker is read only if its centre normal makes at least this cosine with the direction
        towards the camera.
    max_hamming : int
    min_margin : float
        Acceptance thresholds (grey levels for the margin) when the candidates are restricted (the
        tags of the nodes configured at the step: a wrong match needs a near code among few).
    open_max_hamming : int
    open_min_margin : float
        The stricter thresholds used when matching against every code of the family.
    tag_table : mapping, optional
        Tag id -> node id (None: identity).
    """

    layout: StickerLayout = field(default_factory=StickerLayout.around)
    family: str = "tag36h11"
    yaw_steps: int = 45
    min_facing: float = 0.55
    max_hamming: int = 5
    min_margin: float = 4.0
    open_max_hamming: int = 3
    open_min_margin: float = 8.0
    tag_table: Mapping[int, int] | None = None


@dataclass(frozen=True)
class SphereTagRead:
    """A model-based read: tag and node id, hamming, margin, the node's yaw in the observer's root
    frame (ambiguous by the sticker spacing), the sticker index, and the print's outer corners
    (4, 2) in the image (canonical order)."""

    tag: int
    node: int | None
    hamming: int
    margin: float
    yaw: float
    sticker: int
    corners: np.ndarray


class SphereTagReader:
    """Decodes the printed tag of a node from its circle, given the camera model."""

    def __init__(self, config: SphereTagConfig | None = None):
        self.config = config or SphereTagConfig()
        cfg = self.config
        d = cv2.aruco.getPredefinedDictionary(FAMILIES[cfg.family])
        n = d.markerSize + 2
        self._cells = n
        codes = np.array([cv2.aruco.generateImageMarker(d, i, n, borderBits=1) > 127 for i in range(d.bytesList.shape[0])])
        self._codes = codes  # (T, n, n) True = white
        self._data = np.where(codes[:, 1:-1, 1:-1].reshape(len(codes), -1), 1.0, -1.0)  # (T, 36)
        lay = cfg.layout
        h = lay.half_angle
        t = ((np.arange(n) + 0.5) / (n / 2.0) - 1.0) * h  # cell-centre tangent angles, left to right
        s1 = np.tan(t)[None, :]  # columns
        s2 = np.tan(-t)[:, None]  # rows run against up
        axes, up, right = lay.axes, lay.up, lay.right
        nn = axes[:, None, None, :] + s1[None, :, :, None] * right[:, None, None, :] + s2[None, :, :, None] * up[:, None, None, :]
        self._normals = nn / np.linalg.norm(nn, axis=-1, keepdims=True)  # (S, n, n, 3)
        c = np.tan(h)
        corner = np.array([[-c, c], [c, c], [c, -c], [-c, -c]])  # (s1, s2) of TL, TR, BR, BL
        cn = axes[:, None, :] + corner[None, :, 0, None] * right[:, None, :] + corner[None, :, 1, None] * up[:, None, :]
        self._corner_normals = cn / np.linalg.norm(cn, axis=-1, keepdims=True)  # (S, 4, 3)
        yaw = 2 * np.pi * np.arange(cfg.yaw_steps) / cfg.yaw_steps
        cy, sy = np.cos(yaw), np.sin(yaw)
        self._yaws = yaw
        self._Rz = np.zeros((len(yaw), 3, 3))
        self._Rz[:, 0, 0], self._Rz[:, 0, 1], self._Rz[:, 1, 0], self._Rz[:, 1, 1], self._Rz[:, 2, 2] = cy, -sy, sy, cy, 1.0
        # the print's cell normals, sticker axes and corner normals for every yaw, in the observer's
        # root frame (node frames are horizontal): per read only the camera rotation is applied
        self._cells_root = np.einsum("yij,scj->ysci", self._Rz, self._normals.reshape(len(axes), n * n, 3))
        self._axes_root = np.einsum("yij,sj->ysi", self._Rz, axes)  # (Y, S, 3)
        self._corners_root = np.einsum("yij,scj->ysci", self._Rz, self._corner_normals)  # (Y, S, 4, 3)
        self._view_key: tuple | None = None
        self._view = np.zeros((0,), np.float32)

    def _view_cells(self, K: np.ndarray, R_cam: np.ndarray) -> np.ndarray:
        """``n_root^T R_cam K^T`` for every yaw, sticker and cell, (Y, S, n*n, 3) float32 (cached per view)."""
        key = (K.tobytes(), R_cam.tobytes())
        if self._view_key != key:
            self._view_key = key
            self._view = (self._cells_root @ (R_cam @ K.T)).astype(np.float32)
        return self._view

    def node_of(self, tag: int) -> int | None:
        table = self.config.tag_table
        return int(tag) if table is None else (int(table[tag]) if tag in table else None)

    def read(
        self,
        grey: np.ndarray,
        circle: Circle,
        K: np.ndarray,
        R_cam: np.ndarray,
        node_radius: float,
        candidates: Sequence[int] | None = None,
    ) -> SphereTagRead | None:
        """Decode the tag of the node whose eq. (1) circle is ``circle``.

        Parameters
        ----------
        grey : ndarray, shape (H, W), float32
            Lightly smoothed grey image.
        circle : Circle
            The node's eq. (1) circle (:func:`agents.perception.sphere.eq1_circle`).
        K : ndarray, shape (3, 3)
        R_cam : ndarray, shape (3, 3)
            Rotation of the camera in the observer's root horizontal frame.
        node_radius : float
            r0 in metres.
        candidates : sequence of int, optional
            Tag ids to match against (e.g. the tags of the nodes in the log's configuration at this
            step); None: every code of the family.
        """
        cfg = self.config
        K = np.asarray(K, dtype=float)
        R_cam = np.asarray(R_cam, dtype=float)
        f = K[0, 0]
        centre = np.linalg.solve(K, [circle.u, circle.v, 1.0]) * (f * node_radius / circle.r)  # Liu et al. 2024 eq. (1)
        view = -centre / np.linalg.norm(centre)
        # a sticker faces the camera when its axis (root frame) points along the view (root frame)
        facing = self._axes_root @ (R_cam @ view) >= cfg.min_facing  # (Y, S)
        ys, ss = np.nonzero(facing)
        if len(ys) == 0:
            return None
        m, n = len(ys), self._cells
        # image of centre + r0 n_c with n_c = R_cam^T n_root: K centre + r0 n_root^T (R_cam K^T); the
        # second term depends on the camera only, so it is computed once per view
        proj = self._view_cells(K, R_cam)[ys, ss]  # (M, n*n, 3)
        kc = (K @ centre).astype(np.float32)
        r0 = np.float32(node_radius)
        uv = proj[..., :2] * r0 + kc[:2]
        uv /= (proj[..., 2] * r0 + kc[2])[..., None]
        vals = cv2.remap(grey, uv.reshape(m * n, n, 2), None, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE).reshape(m, n, n)
        data = vals[:, 1:-1, 1:-1].reshape(m, -1)
        x = data - data.mean(axis=1, keepdims=True)
        norm = np.linalg.norm(x, axis=1, keepdims=True)
        ids = np.arange(len(self._codes)) if candidates is None else np.array(
            sorted({int(c) for c in candidates if 0 <= int(c) < len(self._codes)}), dtype=int)
        if len(ids) == 0:
            return None
        codes = self._data[ids]
        corr = (x / np.maximum(norm, 1e-9)) @ codes.T / np.sqrt(codes.shape[1])  # (M, T)
        # the border must be darker than the data: weigh by how dark it is relative to the data mean
        border_dark = data.mean(axis=1) - np.concatenate([vals[:, 0, :], vals[:, -1, :], vals[:, 1:-1, 0], vals[:, 1:-1, -1]], axis=1).mean(axis=1)
        corr = corr * (border_dark > 0)[:, None]
        best = np.unravel_index(int(np.argmax(corr)), corr.shape)
        hi, tag = int(best[0]), int(ids[best[1]])
        if corr[best] <= 0:
            return None
        code = self._codes[tag]
        cell = vals[hi]
        white, black = cell[code], cell[~code]
        thr = 0.5 * (white.mean() + black.mean())
        margin = float(min(white.mean() - thr, thr - black.mean()))
        inner = np.zeros_like(code)
        inner[1:-1, 1:-1] = True
        hamming = int(((cell > thr) != code)[inner].sum())
        max_h, min_m = (cfg.max_hamming, cfg.min_margin) if candidates is not None else (cfg.open_max_hamming, cfg.open_min_margin)
        if hamming > max_h or margin < min_m:
            return None
        cp = (K @ centre) + node_radius * (self._corners_root[ys[hi], ss[hi]] @ (R_cam @ K.T))
        corners = cp[:, :2] / cp[:, 2:]
        return SphereTagRead(tag, self.node_of(tag), hamming, margin, float(self._yaws[ys[hi]]), int(ss[hi]), corners)


class SphereTagIdentifier:
    """An :class:`~agents.perception.types.Identifier` reading prints through the sphere model.

    Needs the camera intrinsics and node radius at construction and, before each frame, the camera's
    rotation in the observer's root frame and optionally the candidate tag ids (:meth:`set_view`).
    Circles are taken as silhouettes and turned into eq. (1) circles first.
    """

    def __init__(self, K: np.ndarray, node_radius: float, config: SphereTagConfig | None = None, *, blur: float = 0.5):
        self.reader = SphereTagReader(config)
        self.K = np.asarray(K, dtype=float)
        self.node_radius = float(node_radius)
        self.blur = blur
        self.R_cam: np.ndarray | None = None
        self.candidates: Sequence[int] | None = None

    def set_view(self, R_cam: np.ndarray, candidates: Sequence[int] | None = None) -> None:
        """Camera rotation (3, 3) in the observer's root frame for the next frame, candidate tag ids."""
        self.R_cam = np.asarray(R_cam, dtype=float)
        self.candidates = candidates

    def identify(self, image: np.ndarray, circles) -> list:
        """One :class:`~agents.perception.types.TagRead` (or None) per circle."""
        from agents.perception.hough import _blur_float, to_grey
        from agents.perception.sphere import eq1_circles
        from agents.perception.types import TagRead

        if self.R_cam is None:
            raise ValueError("set_view() must be called before identify()")
        if len(circles) == 0:
            return []
        grey = _blur_float(to_grey(np.asarray(image)), self.blur)
        eq1, _ = eq1_circles(np.array([[c.u, c.v, c.r] for c in circles], dtype=float), self.K)
        out = []
        for c, e in zip(circles, eq1):
            r = self.reader.read(grey, Circle(*map(float, e), c.score), self.K, self.R_cam, self.node_radius, self.candidates)
            out.append(None if r is None else TagRead(r.tag, r.node, r.corners, r.hamming, r.margin, 1.0))
        return out
