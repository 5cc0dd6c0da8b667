"""Rendering camera frames of a simulated world (numpy ray casting + OpenCV effects and files)."""

from sims.render.frame_files import render_frames, write_frames
from sims.render.raycast import StickerLayout
from sims.render.renderer import Frame, RenderConfig, Renderer

__all__ = ["Frame", "RenderConfig", "Renderer", "StickerLayout", "render_frames", "write_frames"]
