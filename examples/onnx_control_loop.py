"""The onboard loop on a vehicle's computer with ONNX Runtime and numpy alone: no torch, no
dockingrl. It runs a program written by ``dockingrl export --format onnx`` over a sensor log
(docs/onboard.md) and prints one command per control step::

    python examples/onnx_control_loop.py policy.onnx log.csv > commands.csv

A vehicle's loop does the same with live messages: at each 0.2 s tick, the readings that
arrived since the last tick (age 0) and the others held with their ages, the current
estimate, and the state the program returned at the previous tick.
"""

import csv
import sys

import numpy as np
import onnxruntime as ort

DT = 0.2  # the control step (s)
SENSORS = ("usbl", "dvl", "imu")
#: the entries of eq. 2's readings [range, bearing, heading, surge, sway, yaw rate] per message
ENTRIES = {"usbl": (0, 1), "dvl": (3, 4), "imu": (2, 5)}


def read_log(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(line for line in f if not line.startswith("#")))
    return [(float(t), kind, float(a), float(b)) for t, kind, a, b in rows[1:]]


def main(program_path, log_path):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(program_path, options, providers=["CPUExecutionProvider"])
    shapes = {i.name: i.shape for i in session.get_inputs()}
    n = shapes["mean"][1]
    state = {
        "mean": np.zeros((1, n), np.float32),
        "cov": np.eye(n, dtype=np.float32)[None],
        "command": np.zeros((1, 2), np.float32),
        "age": -np.ones((1, 1), np.float32),  # -1: a new approach
    }
    if "history" in shapes:  # a filter that compensates the USBL latency
        state["history"] = np.zeros((1, shapes["history"][1], 2), np.float32)
    messages = read_log(log_path)
    latest, arrived, i, tick = {}, {}, 0, 0
    start, end = messages[0][0], messages[-1][0]
    print("t,v_d,w_d")
    while start + tick * DT <= end + 1e-6:
        now = start + tick * DT
        while i < len(messages) and messages[i][0] <= now + 1e-6:
            _, kind, a, b = messages[i]
            latest[kind], arrived[kind] = (a, b), tick
            i += 1
        if all(k in latest for k in (*SENSORS, "current")):
            z = np.zeros((1, 6), np.float32)
            for sensor in SENSORS:
                z[0, list(ENTRIES[sensor])] = latest[sensor]
            ages = np.array([[tick - arrived[s] for s in SENSORS]], np.float32) * np.float32(DT)
            feed = {"z": z, "current": np.array([latest["current"]], np.float32)}
            feed.update(sensor_age=ages, **state)
            names = [o.name for o in session.get_outputs()]
            out = dict(zip(names, session.run(None, feed), strict=True))
            state = {name: out[f"{name}_out"] for name in state}
            command = state["command"][0]
            print(f"{now!r},{float(command[0])!r},{float(command[1])!r}")
        tick += 1


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
