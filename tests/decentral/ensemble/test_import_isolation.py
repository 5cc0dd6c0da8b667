"""Layering: decentral.ensemble loads no OpenCV, PettingZoo, matplotlib or sims code."""

import subprocess
import sys


def test_ensemble_package_imports_only_numerics():
    """Importing decentral.ensemble (and its baselines) leaves cv2, pettingzoo, matplotlib and sims unloaded."""
    code = (
        "import sys, decentral.ensemble, decentral.ensemble.baselines; "
        "bad = [m for m in ('cv2', 'pettingzoo', 'matplotlib', 'sims', 'agents', 'protocols') if m in sys.modules]; "
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
