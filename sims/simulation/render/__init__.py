"""Rendering camera frames of a simulated world (numpy ray casting + OpenCV effects and files)."""

from sims.simulation.render.frame_files import render_frames, write_frames
from sims.simulation.render.raycast import StickerLayout
from sims.simulation.render.renderer import Frame, RenderConfig, Renderer

__all__ = ["Frame", "RenderConfig", "Renderer", "StickerLayout", "render_frames", "write_frames"]
