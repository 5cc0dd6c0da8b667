"""50 robots moving on circles, drawn as an inline SVG pushed by NiceGUI at a target rate (benchmark server)."""

import argparse
import math
import time

from nicegui import ui

ap = argparse.ArgumentParser()
ap.add_argument("--port", type=int, required=True)
ap.add_argument("--robots", type=int, default=50)
ap.add_argument("--hz", type=float, default=20.0)
args = ap.parse_args()


def svg(seq: int) -> str:
    t = time.time()
    parts = [f'<svg viewBox="0 0 500 500" width="500" height="500"><text id="seq" x="5" y="15">{seq}</text>']
    for i in range(args.robots):
        a = t + i * 2 * math.pi / args.robots
        x, y = 250 + 200 * math.cos(a), 250 + 200 * math.sin(a)
        parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="6" fill="#38c"/>'
                     f'<line x1="{x:.1f}" y1="{y:.1f}" x2="{x + 12 * math.cos(a):.1f}" y2="{y + 12 * math.sin(a):.1f}" '
                     'stroke="#000"/>')
    return "".join(parts) + "</svg>"


@ui.page("/")
def index():
    seq = [0]
    view = ui.html(svg(0), sanitize=False)

    def update():
        seq[0] += 1
        view.set_content(svg(seq[0]))

    ui.timer(1.0 / args.hz, update)


ui.run(host="127.0.0.1", port=args.port, reload=False, show=False, show_welcome_message=False)
