"""The console's top view as plain data and as an SVG string (no UI library): testable without a browser.

A :class:`Frame` holds what one picture of the world shows -- true poses, the estimates drawn with
their 2-sigma ellipses, view cones and radio links -- in one planar frame (the swarm's world frame, or
the reference assembly's frame for a log). :func:`svg` draws it; every drawn thing carries ``id`` and
``data-*`` attributes (robot, observer, target, world coordinates), so the browser tests read the page
the way a person looks at it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from html import escape

import numpy as np

__all__ = ["Body", "Mark", "Cone", "Link", "Frame", "ellipse_axes", "svg", "loss_colour"]

#: colours by source of an estimate (Kanovsky: green dot for what the camera saw, red for a report)
SOURCE_COLOURS = {"camera": "#2a9d3a", "mutual": "#1f6fd1", "peer": "#d1342f", "estimate": "#d1342f"}
TRUTH_COLOUR = "#222"
SELECTED_COLOUR = "#f0a400"


@dataclass(frozen=True)
class Body:
    """A true pose: ``name`` at ``(x, y)`` heading ``theta`` [rad], drawn as a disc of ``radius``;
    ``nodes`` (m, 2) are extra node centres (an assembly's modules) in the same frame."""

    name: str
    x: float
    y: float
    theta: float
    radius: float
    nodes: tuple = ()


@dataclass(frozen=True)
class Mark:
    """An estimate of ``target`` held by ``observer``, at ``(x, y)`` with position covariance ``cov`` (2, 2)."""

    observer: str
    target: str
    x: float
    y: float
    theta: float | None
    cov: np.ndarray | None
    source: str = "estimate"
    error: float | None = None


@dataclass(frozen=True)
class Cone:
    """A camera's view cone: apex ``(x, y)``, centre line ``theta``, half-angle and range."""

    robot: str
    x: float
    y: float
    theta: float
    half_angle: float
    distance: float
    selected: bool = False


@dataclass(frozen=True)
class Link:
    """A radio link ``a``-``b`` and its recent loss in [0, 1] (``None``: nothing sent lately)."""

    a: str
    b: str
    loss: float | None


@dataclass(frozen=True)
class Frame:
    """Everything one view draws, in one planar frame whose bounds are ``(xmin, ymin, xmax, ymax)``."""

    bounds: tuple
    bodies: tuple = ()
    marks: tuple = ()
    cones: tuple = ()
    links: tuple = ()
    selected: str | None = None
    truth_marks: tuple = field(default=())  # extra bodies drawn as outlines (truth of a replay)
    label: str = ""


def ellipse_axes(cov: np.ndarray, sigmas: float = 2.0) -> tuple[float, float, float]:
    """Semi-axes ``(a, b)`` [m] and angle [deg] of the ``sigmas`` ellipse of a (2, 2) covariance."""
    cov = 0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T)
    w, v = np.linalg.eigh(cov)
    w = np.clip(w, 0.0, None)
    return sigmas * math.sqrt(w[1]), sigmas * math.sqrt(w[0]), math.degrees(math.atan2(v[1, 1], v[0, 1]))


def loss_colour(loss: float | None) -> str:
    """Green (no loss) through yellow to red (all lost); grey when nothing was sent."""
    if loss is None or not math.isfinite(loss):
        return "#bbbbbb"
    loss = min(max(loss, 0.0), 1.0)
    r = int(255 * min(1.0, 2 * loss))
    g = int(200 * min(1.0, 2 * (1 - loss)))
    return f"#{r:02x}{g:02x}30"


def _f(v: float) -> str:
    return f"{v:.3f}"


def svg(frame: Frame, width: int = 640) -> str:
    """The frame as an SVG string (y up; 1 unit = 1 m), ``width`` pixels wide."""
    x0, y0, x1, y1 = frame.bounds
    span = max(x1 - x0, y1 - y0, 1e-6)
    height = int(round(width * (y1 - y0) / max(x1 - x0, 1e-6)))
    stroke = span / 400
    r_min = span / 140
    parts = [f'<svg id="topview" xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'viewBox="{_f(x0)} {_f(-y1)} {_f(x1 - x0)} {_f(y1 - y0)}" style="background:#fafafa;border:1px solid #ccc">',
             f'<g transform="scale(1,-1)" stroke-width="{_f(stroke)}">']
    pos = {b.name: b for b in frame.bodies}
    for link in frame.links:
        a, b = pos.get(link.a), pos.get(link.b)
        if a is None or b is None:
            continue
        loss = "" if link.loss is None or not math.isfinite(link.loss) else f"{link.loss:.3f}"
        parts.append(f'<line class="link" data-a="{escape(link.a)}" data-b="{escape(link.b)}" data-loss="{loss}" '
                     f'x1="{_f(a.x)}" y1="{_f(a.y)}" x2="{_f(b.x)}" y2="{_f(b.y)}" stroke="{loss_colour(link.loss)}" '
                     f'stroke-opacity="0.7"/>')
    for cone in frame.cones:
        lx = cone.x + cone.distance * math.cos(cone.theta + cone.half_angle)
        ly = cone.y + cone.distance * math.sin(cone.theta + cone.half_angle)
        rx = cone.x + cone.distance * math.cos(cone.theta - cone.half_angle)
        ry = cone.y + cone.distance * math.sin(cone.theta - cone.half_angle)
        fill, opacity = (SELECTED_COLOUR, 0.18) if cone.selected else ("#7799cc", 0.05)
        parts.append(f'<path class="cone" data-robot="{escape(cone.robot)}" d="M {_f(cone.x)} {_f(cone.y)} '
                     f'L {_f(rx)} {_f(ry)} A {_f(cone.distance)} {_f(cone.distance)} 0 0 1 {_f(lx)} {_f(ly)} Z" '
                     f'fill="{fill}" fill-opacity="{opacity}" stroke="{fill}" stroke-opacity="{2 * opacity}"/>')
    for body in frame.truth_marks:
        parts.append(f'<circle class="truth-outline" data-robot="{escape(body.name)}" data-x="{_f(body.x)}" '
                     f'data-y="{_f(body.y)}" cx="{_f(body.x)}" cy="{_f(body.y)}" r="{_f(max(body.radius, r_min) * 1.6)}" '
                     f'fill="none" stroke="{TRUTH_COLOUR}" stroke-dasharray="{_f(2 * stroke)}"/>')
    for m in frame.marks:
        colour = SOURCE_COLOURS.get(m.source, "#d1342f")
        ell = ""
        if m.cov is not None:
            a, b, ang = ellipse_axes(m.cov)
            a, b = min(a, span), min(b, span)
            ell = (f'<ellipse cx="{_f(m.x)}" cy="{_f(m.y)}" rx="{_f(max(a, stroke))}" ry="{_f(max(b, stroke))}" '
                   f'transform="rotate({ang:.2f} {_f(m.x)} {_f(m.y)})" fill="{colour}" fill-opacity="0.08" '
                   f'stroke="{colour}" stroke-opacity="0.6"/>')
        err = "" if m.error is None else f' data-error="{m.error:.4f}"'
        s = r_min * 0.8
        parts.append(f'<g class="est" data-observer="{escape(m.observer)}" data-target="{escape(m.target)}" '
                     f'data-x="{_f(m.x)}" data-y="{_f(m.y)}" data-source="{escape(m.source)}"{err}>{ell}'
                     f'<path d="M {_f(m.x - s)} {_f(m.y - s)} L {_f(m.x + s)} {_f(m.y + s)} M {_f(m.x - s)} {_f(m.y + s)} '
                     f'L {_f(m.x + s)} {_f(m.y - s)}" stroke="{colour}" stroke-width="{_f(2 * stroke)}"/></g>')
    for body in frame.bodies:
        r = max(body.radius, r_min)
        sel = body.name == frame.selected
        colour = SELECTED_COLOUR if sel else "#4a90d9"
        hx, hy = body.x + 2.2 * r * math.cos(body.theta), body.y + 2.2 * r * math.sin(body.theta)
        nodes = "".join(f'<circle cx="{_f(nx)}" cy="{_f(ny)}" r="{_f(r * 0.6)}" fill="#9bbde6" stroke="none"/>'
                        for nx, ny in body.nodes)
        parts.append(f'<g class="truth" id="truth-{escape(body.name)}" data-robot="{escape(body.name)}" '
                     f'data-x="{_f(body.x)}" data-y="{_f(body.y)}" data-theta="{body.theta:.4f}" '
                     f'data-selected="{int(sel)}">{nodes}<circle cx="{_f(body.x)}" cy="{_f(body.y)}" r="{_f(r)}" '
                     f'fill="{colour}" stroke="{TRUTH_COLOUR}"/><line x1="{_f(body.x)}" y1="{_f(body.y)}" x2="{_f(hx)}" '
                     f'y2="{_f(hy)}" stroke="{TRUTH_COLOUR}" stroke-width="{_f(2 * stroke)}"/></g>')
    parts.append("</g>")
    fs = span / 45
    for body in frame.bodies:
        r = max(body.radius, r_min)
        parts.append(f'<text x="{_f(body.x + 1.3 * r)}" y="{_f(-body.y - 1.3 * r)}" font-size="{_f(fs)}" '
                     f'fill="#333">{escape(body.name)}</text>')
    if frame.label:
        parts.append(f'<text id="frame-label" x="{_f(x0 + fs * 0.3)}" y="{_f(-y1 + fs * 1.1)}" font-size="{_f(fs)}" '
                     f'fill="#555">{escape(frame.label)}</text>')
    parts.append("</svg>")
    return "".join(parts)
