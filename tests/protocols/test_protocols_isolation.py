"""Layering: the protocols layer loads no OpenCV, PettingZoo or matplotlib."""

import subprocess
import sys


def test_protocols_import_no_heavy_frontends():
    """Importing protocols (and decentral.filtering) in a fresh interpreter loads neither cv2, pettingzoo nor matplotlib."""
    code = (
        "import sys, protocols, protocols.network, protocols.consensus, decentral.filtering, decentral.averaging;"
        "print(','.join(m for m in ('cv2', 'pettingzoo', 'matplotlib') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
