"""The learned detector's two networks (PyTorch; the ``train`` extra).

- :class:`CircleNet`: a CenterNet-style [1]_ network on the frame resized to the input size (the
  shipped one 384 x 288, the first releases 256 x 192): a small pyramid of depthwise-separable
  blocks (strides 4-32) merged top-down to stride 4, and one output of 4 channels on the grid of
  stride 4 (96 x 72 at 384 x 288): the centre heatmap (sigmoid), the log radius in input pixels,
  and the centre's sub-cell offset (x, y).
- :class:`RefineNet`: the second stage, on a 32 x 32 window 2.5 proposal radii wide around each
  proposal: the true circle relative to the proposal (du / r, dv / r, log(r / r_p)).

Both use only convolutions, batch normalisation, ReLU, nearest upsampling, additions, pooling and
linear layers, which OpenCV's ``dnn`` and onnxruntime both run.

References
----------
.. [1] X. Zhou, D. Wang and P. Kraehenbuehl, "Objects as points", arXiv:1904.07850, 2019.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["CircleNet", "RefineNet"]


def _conv(ci: int, co: int, stride: int = 1, k: int = 3, groups: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(ci, co, k, stride, k // 2, groups=groups, bias=False), nn.BatchNorm2d(co),
                         nn.ReLU(inplace=True))


class _Block(nn.Module):
    """Depthwise 3 x 3 then pointwise 1 x 1; residual when the shape is kept."""

    def __init__(self, ci: int, co: int, stride: int = 1):
        super().__init__()
        self.dw = _conv(ci, ci, stride, 3, groups=ci)
        self.pw = nn.Sequential(nn.Conv2d(ci, co, 1, bias=False), nn.BatchNorm2d(co))
        self.residual = stride == 1 and ci == co

    def forward(self, x):
        y = self.pw(self.dw(x))
        return F.relu(y + x if self.residual else y)


def _stage(ci: int, co: int, n: int) -> nn.Sequential:
    return nn.Sequential(_Block(ci, co, 2), *[_Block(co, co) for _ in range(n - 1)])


class CircleNet(nn.Module):
    """Frame (B, 3, H, W) in [-0.5, 0.5] -> (B, 4, H / 4, W / 4): heatmap, log radius, offset x, offset y.

    H and W must be multiples of 32 (e.g. 256 x 192, 384 x 288). ``channels``: the stem's first
    convolution and the four pyramid levels (strides 4, 8, 16, 32); ``width``: the merged top-down
    features and the head.
    """

    def __init__(self, width: int = 48, channels: tuple[int, ...] = (16, 32, 64, 96, 128)):
        super().__init__()
        c0, c4, c8, c16, c32 = channels
        self.config = {"width": int(width), "channels": [int(c) for c in channels]}
        self.stem = nn.Sequential(_conv(3, c0, 2), _conv(c0, c4, 2), _Block(c4, c4), _Block(c4, c4))  # stride 4
        self.s8 = _stage(c4, c8, 3)
        self.s16 = _stage(c8, c16, 3)
        self.s32 = _stage(c16, c32, 3)
        self.lat = nn.ModuleList([nn.Conv2d(c, width, 1) for c in (c4, c8, c16, c32)])
        self.head = nn.Sequential(_Block(width, width), _Block(width, width), nn.Conv2d(width, 4, 1))
        nn.init.constant_(self.head[-1].bias, 0.0)
        with torch.no_grad():
            self.head[-1].bias[0] = -2.19  # heatmap prior 0.1 (Lin et al. 2017's focal-loss start)
            self.head[-1].bias[1] = 2.5  # log radius of ~12 input px

    def forward(self, x):
        out = self.logits(x)
        return torch.cat([torch.sigmoid(out[:, :1]), out[:, 1:]], dim=1)

    def logits(self, x):
        """The same output with the heatmap before the sigmoid (for the loss)."""
        c4 = self.stem(x)
        c8 = self.s8(c4)
        c16 = self.s16(c8)
        c32 = self.s32(c16)
        y = self.lat[3](c32)
        for lat, c in ((self.lat[2], c16), (self.lat[1], c8), (self.lat[0], c4)):
            y = F.interpolate(y, scale_factor=2.0, mode="nearest") + lat(c)
        return self.head(y)


class RefineNet(nn.Module):
    """Window (B, 3, 32, 32) in [-0.5, 0.5] -> (B, 3): du / r_p, dv / r_p, log(r / r_p)."""

    def __init__(self):
        super().__init__()
        self.features = nn.Sequential(
            _conv(3, 24), _conv(24, 24), nn.MaxPool2d(2),  # 16
            _conv(24, 48), _conv(48, 48), nn.MaxPool2d(2),  # 8
            _conv(48, 64), _conv(64, 64), nn.MaxPool2d(2),  # 4
            _conv(64, 96))
        self.fc = nn.Sequential(nn.Flatten(), nn.Linear(96 * 16, 128), nn.ReLU(inplace=True), nn.Linear(128, 3))

    def forward(self, x):
        return self.fc(self.features(x))
