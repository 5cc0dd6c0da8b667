"""50 robots moving on circles in a Bokeh figure, patched by Panel at a target rate (benchmark server)."""

import argparse
import math
import time

import panel as pn
from bokeh.models import ColumnDataSource
from bokeh.plotting import figure

ap = argparse.ArgumentParser()
ap.add_argument("--port", type=int, required=True)
ap.add_argument("--robots", type=int, default=50)
ap.add_argument("--hz", type=float, default=20.0)
args = ap.parse_args()


def data(seq: int) -> dict:
    t = time.time()
    a = [t + i * 2 * math.pi / args.robots for i in range(args.robots)]
    return {"x": [2 * math.cos(v) for v in a], "y": [2 * math.sin(v) for v in a], "seq": [seq] * args.robots}


def app():
    src = ColumnDataSource(data(0), name="src")
    fig = figure(width=500, height=500, x_range=(-3, 3), y_range=(-3, 3))
    fig.scatter("x", "y", source=src, size=10)
    seq = [0]

    def update():
        seq[0] += 1
        src.data = data(seq[0])

    pn.state.add_periodic_callback(update, period=int(1000 / args.hz))
    return pn.pane.Bokeh(fig)


pn.serve({"/": app}, port=args.port, address="127.0.0.1", show=False, websocket_origin=[f"127.0.0.1:{args.port}"],
         threaded=False)
