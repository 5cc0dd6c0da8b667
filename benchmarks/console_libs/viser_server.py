"""50 robots moving on circles as viser scene nodes, updated at a target rate (benchmark server)."""

import argparse
import math
import time

import viser

ap = argparse.ArgumentParser()
ap.add_argument("--port", type=int, required=True)
ap.add_argument("--robots", type=int, default=50)
ap.add_argument("--hz", type=float, default=20.0)
args = ap.parse_args()

server = viser.ViserServer(host="127.0.0.1", port=args.port, verbose=False)
robots = [server.scene.add_icosphere(f"/robot{i}", radius=0.06, color=(50, 130, 200)) for i in range(args.robots)]
seq = server.gui.add_number("seq", initial_value=0)
k = 0
while True:
    t = time.time()
    k += 1
    with server.atomic():
        for i, h in enumerate(robots):
            a = t + i * 2 * math.pi / args.robots
            h.position = (2 * math.cos(a), 2 * math.sin(a), 0.0)
        seq.value = k
    time.sleep(max(0.0, 1.0 / args.hz - (time.time() - t)))
