"""Varied image sequences of tagged spheres for testing perception on frames it was not tuned on.

A robot's camera does not see the tidy frames of one renderer: spheres whose colour is close to the
floor's, of 15-90 px radius, on floors of several textures under uneven light with specular
highlights, an AprilTag 36h11 squeezed onto the cap wherever the node happens to face, spheres
passing in front of each other, struts across them, tags smeared by motion. :func:`sequence` draws
such a sequence directly in the image plane (no 3-D world), with the exact circle, visible fraction
and tag of every sphere in every frame, from one seed.

Seeds: :data:`TUNING_SEEDS` are the scenes the perception parameters were developed on;
:data:`HELD_OUT_SEEDS` are scenes no parameter was tuned on, reported separately by
``benchmarks/perception.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from sims.lab.experiments.synthetic_scene import disc_patch
from sims.simulation.render.effects import motion_kernel
from sims.simulation.render.surfaces import SURFACES, lighting_gradient, surface
from sims.simulation.render.textures import TAG_IDS, tag_cells

__all__ = [
    "TUNING_SEEDS", "HELD_OUT_SEEDS", "Sphere", "Strut", "Look", "Frame", "render", "sequence",
    "Mover", "random_look", "random_tag_normal", "random_mover", "random_struts", "animate",
]

#: scene seeds the detector and tracker parameters were developed on (0-7 for the rim detector,
#: 0-31 for the symmetry detector)
TUNING_SEEDS = tuple(range(0, 32))
#: scene seeds no parameter was tuned on (report these)
HELD_OUT_SEEDS = tuple(range(1000, 1008))

_TAG_PX = 8  # texture pixels per tag cell


@dataclass(frozen=True)
class Sphere:
    """One sphere in one frame.

    Attributes
    ----------
    id : int
        Node id (its tag id when ``tag`` is True).
    u, v, r : float
        Silhouette circle in pixels (OpenCV convention, pixel centres at integers).
    colour : tuple of 3 floats
        Diffuse reflectance, BGR in [0, 1].
    tag : bool
        Whether the node carries its 36h11 tag (id ``id``) on this side.
    tag_normal : tuple of 3 floats
        Unit direction from the sphere's centre to the tag's centre, camera frame (x right, y down,
        z towards the camera): z = 1 faces the camera, z < 0 is on the far side.
    tag_spin : float
        In-plane rotation of the tag about its normal (rad).
    tag_half_angle : float
        Half the angular size of the printed square as seen from the sphere's centre (rad).
    paper : bool
        The tag is printed on white paper with a one-cell quiet zone (else straight on the sphere:
        its white cells are the sphere's colour).
    velocity : tuple of 2 floats
        Image motion (px) during the exposure: the sphere is smeared along it.
    specular : float
        Strength of the specular highlight (0-1).
    """

    id: int
    u: float
    v: float
    r: float
    colour: tuple[float, float, float]
    tag: bool = True
    tag_normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    tag_spin: float = 0.0
    tag_half_angle: float = 0.4
    paper: bool = True
    velocity: tuple[float, float] = (0.0, 0.0)
    specular: float = 0.3


@dataclass(frozen=True)
class Strut:
    """A bar in front of the spheres (a strut of the robot seen from the side), ``p0`` to ``p1`` in px."""

    p0: tuple[float, float]
    p1: tuple[float, float]
    width: float
    colour: tuple[float, float, float]


@dataclass(frozen=True)
class Look:
    """The scene-wide appearance: lighting, camera degradations.

    ``light`` is the direction towards the light (camera frame), ``ambient`` the unlit share of a
    sphere's brightness, ``noise`` the sensor noise (grey levels), ``blur`` the optical blur (px),
    ``gain`` the exposure, ``jpeg`` the JPEG quality (0: off), ``shadow`` the darkening under a sphere.
    """

    light: tuple[float, float, float] = (-0.4, -0.5, 0.77)
    ambient: float = 0.35
    noise: float = 2.0
    blur: float = 0.6
    gain: float = 1.0
    jpeg: int = 0
    shadow: float = 0.35


@dataclass(frozen=True)
class Frame:
    """A rendered frame and its truth.

    ``image`` is (H, W, 3) uint8 BGR; ``spheres`` the spheres drawn (far to near); ``visible`` the
    fraction of each sphere's disc that shows (inside the image, not behind a nearer sphere or a
    strut), in the order of ``spheres``.
    """

    image: np.ndarray
    spheres: tuple[Sphere, ...]
    visible: np.ndarray


def _tag_texture(tag: int, paper: bool) -> tuple[np.ndarray, float]:
    """The tag's print (reflectance factor, float32, 1 = the surface's white) and its half size in cells."""
    cells = tag_cells(tag).astype(np.float32)
    if paper:
        cells = np.pad(cells, 1, constant_values=1.0)
    big = cv2.resize(cells, None, fx=_TAG_PX, fy=_TAG_PX, interpolation=cv2.INTER_NEAREST)
    return 0.06 + 0.94 * big, cells.shape[0] / 2.0


def _tag_frame(normal: np.ndarray, spin: float) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (right, down) of a tag centred on ``normal``, spun by ``spin``."""
    up = np.array([0.0, 1.0, 0.0]) if abs(normal[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(up, normal)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    c, s = np.cos(spin), np.sin(spin)
    return c * e1 + s * e2, -s * e1 + c * e2


def _draw_sphere(img: np.ndarray, label: np.ndarray, index: int, sp: Sphere, look: Look, light: np.ndarray,
                 gradient: np.ndarray) -> None:
    """Composite one sphere (shaded, tagged, smeared along its velocity) onto ``img`` and ``label``."""
    h, w = label.shape
    smear = float(np.hypot(*sp.velocity))
    patch = disc_patch(sp.u, sp.v, sp.r, int(np.ceil(smear / 2.0)) + 3, w, h)
    if patch is None:
        return
    x0, y0, dx, dy, alpha, nz = patch
    x1, y1 = x0 + dx.shape[1], y0 + dx.shape[0]
    ndl = np.clip(dx * light[0] + dy * light[1] + nz * light[2], 0.0, 1.0)
    reflect = 2.0 * ndl * nz - light[2]  # z of the mirrored light direction: the view is +z
    spec = sp.specular * np.clip(reflect, 0.0, 1.0) ** 30
    albedo = np.broadcast_to(np.asarray(sp.colour, np.float32), alpha.shape + (3,)).copy()
    if sp.tag:
        tex, half_cells = _tag_texture(sp.id, sp.paper)
        t = np.asarray(sp.tag_normal, dtype=float)
        t /= np.linalg.norm(t)
        e1, e2 = _tag_frame(t, sp.tag_spin)
        n = np.stack([dx, dy, nz], axis=2)
        along = n @ t
        a = np.arctan2(n @ e1, along) / sp.tag_half_angle  # -1..1 across the print
        b = np.arctan2(n @ e2, along) / sp.tag_half_angle
        on = (along > 0) & (np.abs(a) < 1) & (np.abs(b) < 1) & (alpha > 0)
        if on.any():
            size = tex.shape[0]
            mx = ((a + 1.0) * 0.5 * size - 0.5).astype(np.float32)
            my = ((b + 1.0) * 0.5 * size - 0.5).astype(np.float32)
            factor = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1.0)
            white = np.full(3, 0.9, np.float32) if sp.paper else np.asarray(sp.colour, np.float32)
            albedo[on] = white[None, :] * factor[on][:, None]
    shade = (look.ambient + (1.0 - look.ambient) * ndl)[:, :, None]
    colour = (albedo * shade + spec[:, :, None]) * gradient[y0:y1, x0:x1, None]
    colour *= alpha[:, :, None]
    kernel = motion_kernel(*sp.velocity)
    if kernel is not None:  # premultiplied colour and coverage smear together
        colour = cv2.filter2D(colour, -1, kernel, borderType=cv2.BORDER_CONSTANT)
        alpha = cv2.filter2D(alpha, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    patch = img[y0:y1, x0:x1]
    patch *= (1.0 - alpha)[:, :, None]
    patch += colour
    label[y0:y1, x0:x1][alpha > 0.5] = index


def _draw_shadow(img: np.ndarray, sp: Sphere, light: np.ndarray, strength: float) -> None:
    """Darken the floor under and beside a sphere (a soft blob pushed away from the light)."""
    h, w = img.shape[:2]
    off = -np.asarray(light[:2]) / max(light[2], 0.3) * 0.35 * sp.r
    cu, cv = sp.u + off[0], sp.v + off[1] + 0.3 * sp.r
    x0, x1 = max(int(cu - 2 * sp.r), 0), min(int(cu + 2 * sp.r) + 1, w)
    y0, y1 = max(int(cv - 2 * sp.r), 0), min(int(cv + 2 * sp.r) + 1, h)
    if x0 >= x1 or y0 >= y1:
        return
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    q = ((xs - cu) / (1.1 * sp.r)) ** 2 + ((ys - cv) / (0.8 * sp.r)) ** 2
    img[y0:y1, x0:x1] *= (1.0 - strength * np.exp(-1.5 * q))[:, :, None]  # soft: a room's diffuse light


def render(spheres: tuple[Sphere, ...], struts: tuple[Strut, ...], look: Look, floor: np.ndarray,
           gradient: np.ndarray, rng: np.random.Generator, *, shake: tuple[float, float] = (0.0, 0.0)) -> Frame:
    """Draw one frame: floor, shadows, spheres far to near (smaller first), struts, camera effects.

    Parameters
    ----------
    floor : ndarray, shape (H, W, 3)
        Reflectance of the background (see :mod:`sims.simulation.render.surfaces`).
    gradient : ndarray, shape (H, W)
        Illumination factor (:func:`sims.simulation.render.surfaces.lighting_gradient`).
    rng : numpy.random.Generator
        Draws the sensor noise.
    shake : (dx, dy)
        Camera motion during the exposure (px): the whole frame is smeared along it.
    """
    h, w = floor.shape[:2]
    light = np.asarray(look.light, dtype=float)
    light /= np.linalg.norm(light)
    order = sorted(range(len(spheres)), key=lambda i: spheres[i].r)
    spheres = tuple(spheres[i] for i in order)
    img = floor * gradient[:, :, None]
    for sp in spheres:
        _draw_shadow(img, sp, light, look.shadow)
    label = np.full((h, w), -1, np.int32)
    for i, sp in enumerate(spheres):
        _draw_sphere(img, label, i, sp, look, light, gradient)
    strut_mask = np.zeros((h, w), np.uint8)
    for st in struts:
        p0, p1 = tuple(int(round(x)) for x in st.p0), tuple(int(round(x)) for x in st.p1)
        cv2.line(img, p0, p1, tuple(float(c) for c in st.colour), int(round(st.width)), lineType=cv2.LINE_AA)
        cv2.line(strut_mask, p0, p1, 1, int(round(st.width)))
    label[strut_mask > 0] = -2
    counts = np.bincount(label[label >= 0].ravel(), minlength=len(spheres))
    visible = counts / np.maximum(np.pi * np.array([s.r for s in spheres]) ** 2, 1.0)
    kernel = motion_kernel(*shake)
    if kernel is not None:
        img = cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REPLICATE)
    if look.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), look.blur)
    img = img * np.float32(255.0 * look.gain)
    if look.noise > 0:
        img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(look.noise)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if look.jpeg:
        ok, data = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(look.jpeg)])
        out = cv2.imdecode(data, cv2.IMREAD_COLOR) if ok else out
    return Frame(out, spheres, np.minimum(visible, 1.0))


# ----------------------------------------------------------------------------- random sequences


@dataclass
class Mover:
    """A sphere's state while a sequence is generated (position, velocity, size, tag orientation)."""

    sphere: Sphere
    vel: np.ndarray
    base_r: float
    phase: float
    rot_axis: np.ndarray
    rot_rate: float


def _colour_near(rng: np.random.Generator, ref: np.ndarray, spread: float) -> tuple[float, float, float]:
    return tuple(float(x) for x in np.clip(ref + rng.uniform(-spread, spread, 3), 0.04, 0.96))


def random_look(rng: np.random.Generator, *, elevation: tuple[float, float] = (0.35, 1.2),
                ambient: tuple[float, float] = (0.25, 0.55), noise: tuple[float, float] = (1.0, 6.0),
                blur: tuple[float, float] = (0.0, 1.1), gain: tuple[float, float] = (0.8, 1.2),
                jpeg: tuple[int, ...] = (0, 0, 70, 85), shadow: tuple[float, float] = (0.05, 0.25)) -> Look:
    """A :class:`Look` drawn from ``rng``: each field uniform in its range (``jpeg``: one of the listed qualities).

    The light comes from a uniform azimuth at an elevation (rad above the image plane) in
    ``elevation``. The defaults are the varied scenes' ranges.
    """
    az = rng.uniform(0, 2 * np.pi)
    elev = rng.uniform(*elevation)
    light = (np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), np.sin(elev))
    return Look(light=light, ambient=float(rng.uniform(*ambient)), noise=float(rng.uniform(*noise)),
                blur=float(rng.uniform(*blur)), gain=float(rng.uniform(*gain)),
                jpeg=int(rng.choice(list(jpeg))), shadow=float(rng.uniform(*shadow)))


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation of ``v`` about unit ``axis`` by ``angle``."""
    c, s = np.cos(angle), np.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * np.dot(axis, v) * (1 - c)


def random_tag_normal(rng: np.random.Generator, max_polar: float) -> tuple[float, float, float]:
    """A unit tag direction (camera frame) at most ``max_polar`` rad from facing the camera (draws polar, azimuth)."""
    polar, az = rng.uniform(0.0, max_polar), rng.uniform(0, 2 * np.pi)
    return (np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az), np.cos(polar))


def random_mover(rng: np.random.Generator, tag_id: int, u: float, v: float, r: float,
                 colour: tuple[float, float, float], *, tag: bool, tag_normal: tuple[float, float, float],
                 max_specular: float, speed: float) -> Mover:
    """A sphere at (``u``, ``v``, ``r``) px and its motion; the rest drawn from ``rng``.

    Draws, in this order: tag spin, tag half-angle (0.3-0.5 rad), paper (probability 0.6),
    specular strength (0 to ``max_specular``), the tag's rotation axis, the velocity (normal, standard
    deviation ``speed`` px per frame per axis), the size phase and the tag's rotation rate (0-0.08 rad
    per frame). The generators rely on this order: their scenes are reproduced from seeds.
    """
    sp = Sphere(tag_id, u, v, r, colour, tag=tag, tag_normal=tag_normal, tag_spin=float(rng.uniform(-np.pi, np.pi)),
                tag_half_angle=float(rng.uniform(0.3, 0.5)), paper=bool(rng.random() < 0.6),
                specular=float(rng.uniform(0.0, max_specular)))
    axis = rng.standard_normal(3)
    return Mover(sp, rng.normal(0.0, speed, 2), r, float(rng.uniform(0, 2 * np.pi)),
                 axis / np.linalg.norm(axis), float(rng.uniform(0.0, 0.08)))


def random_struts(rng: np.random.Generator, width: int, height: int, *, count: tuple[int, int], spread: float,
                  widths: tuple[float, float], greys: tuple[float, float]) -> list[tuple[Strut, np.ndarray]]:
    """Struts and their velocities (px per frame), drawn from ``rng``.

    ``count`` is the inclusive range of the number of struts; each starts anywhere in the frame, ends
    a normal offset of standard deviation ``spread`` px away, is ``widths`` px wide and grey
    (``greys``, slightly tinted) and moves with a velocity of standard deviation 1.5 px per frame.
    """
    struts = []
    for _ in range(int(rng.integers(count[0], count[1] + 1))):
        p0 = rng.uniform([0, 0], [width, height])
        p1 = p0 + rng.normal(0, spread, 2)
        grey = rng.uniform(*greys)
        struts.append((Strut(tuple(p0), tuple(p1), float(rng.uniform(*widths)),
                             (grey, grey, grey * rng.uniform(0.9, 1.1))),
                       rng.normal(0, 1.5, 2)))
    return struts


def animate(movers: list[Mover], struts: list[tuple[Strut, np.ndarray]], look: Look, floor: np.ndarray,
            gradient: np.ndarray, noise_rng: np.random.Generator, motion_rng: np.random.Generator, frames: int, *,
            radius: tuple[float, float], jitter: float, wobble: float, margin: float) -> list[Frame]:
    """Move the scene's spheres and struts for ``frames`` frames and render each (see :func:`sequence`).

    Per frame (from ``motion_rng``): now and then a jerk (the spheres move 2.5 times as far, the
    exposure is up to 0.9 of the frame interval) or camera shake; each sphere's velocity is damped
    and kicked by normal noise of standard deviation ``jitter`` px, its radius swings by up to
    ``wobble`` (a fraction, clipped to ``radius``), it bounces back once its centre is more than
    ``margin`` radii outside the frame, and its tag turns about the mover's axis. ``movers`` are
    updated in place. ``noise_rng`` draws the sensor noise (:func:`render`).
    """
    height, width = floor.shape[:2]
    out = []
    for k in range(frames):
        jerk = motion_rng.random() < 0.15  # a fast frame: tags smeared
        shutter = motion_rng.uniform(0.1, 0.9) if jerk else motion_rng.uniform(0.05, 0.4)
        shake = tuple(motion_rng.normal(0, 4.0, 2)) if motion_rng.random() < 0.08 else (0.0, 0.0)
        drawn = []
        for m in movers:
            m.vel = 0.9 * m.vel + motion_rng.normal(0.0, jitter, 2)
            step = m.vel * (2.5 if jerk else 1.0)
            sp = m.sphere
            r = float(np.clip(m.base_r * (1.0 + wobble * np.sin(0.07 * k + m.phase)), radius[0], radius[1]))
            u, v = sp.u + step[0], sp.v + step[1]
            if not -margin * r < u < width + margin * r:
                m.vel[0] = -m.vel[0]
            if not -margin * r < v < height + margin * r:
                m.vel[1] = -m.vel[1]
            normal = _rotate(np.asarray(sp.tag_normal), m.rot_axis, m.rot_rate)
            smear = step * shutter  # the exposure is a fraction of the frame interval
            m.sphere = replace(sp, u=float(u), v=float(v), r=r, tag_normal=tuple(normal), velocity=tuple(smear))
            drawn.append(m.sphere)
        struts = [(Strut(tuple(np.asarray(st.p0) + vel), tuple(np.asarray(st.p1) + vel), st.width, st.colour), vel)
                  for st, vel in struts]
        out.append(render(tuple(drawn), tuple(s for s, _ in struts), look, floor, gradient, noise_rng, shake=shake))
    return out


def sequence(seed: int, frames: int = 30, *, width: int = 1024, height: int = 768,
             spheres: tuple[int, int] = (5, 10), radius: tuple[float, float] = (15.0, 90.0)) -> list[Frame]:
    """A varied sequence of ``frames`` frames from scene ``seed``.

    Per scene (from the seed): a surface kind, lighting gradient, light direction, camera
    degradations, 5-10 spheres (radius log-uniform in ``radius``, about a third of them coloured
    within a few per cent of the floor's mean colour), 0-3 struts. Per frame: smooth motion (spheres
    bounce off the borders and pass in front of each other; nearer = larger), slow changes of size,
    tags that turn with the node (sometimes to the far side), and now and then a jerk (the spheres move
    2.5 times as far, and the exposure is up to 0.9 of the frame interval) that smears the tags or shakes the camera.
    """
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    floor_rng, noise_rng, motion_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    kind = list(SURFACES)[int(rng.integers(0, len(SURFACES)))]
    floor = surface(kind, floor_rng, height, width)
    gradient = lighting_gradient(floor_rng, height, width)
    look = random_look(rng)
    floor_mean = floor[height // 3:].reshape(-1, 3).mean(axis=0)
    n = int(rng.integers(spheres[0], spheres[1] + 1))
    ids = rng.choice(TAG_IDS, size=n, replace=False)
    movers = []
    for i in range(n):
        r = float(np.exp(rng.uniform(np.log(radius[0]), np.log(radius[1]))))
        colour = _colour_near(rng, floor_mean, 0.06) if rng.random() < 0.35 else _colour_near(rng, rng.uniform(0.15, 0.85, 3), 0.0)
        normal = random_tag_normal(rng, 1.1)
        u, v = float(rng.uniform(r, width - r)), float(rng.uniform(r, height - r))
        movers.append(random_mover(rng, int(ids[i]), u, v, r, colour, tag=True, tag_normal=normal,
                                   max_specular=0.6, speed=4.0))
    struts = random_struts(rng, width, height, count=(0, 3), spread=200, widths=(5, 16), greys=(0.1, 0.8))
    return animate(movers, struts, look, floor, gradient, noise_rng, motion_rng, frames,
                   radius=radius, jitter=1.2, wobble=0.12, margin=0.3)
