"""A third-party agent written from docs/protocol.md alone: raw zenoh calls, no fedlab code.

    python tests/integration/third_party_agent.py ENDPOINT LAB/NAME CLOCK_OFFSET DURATION

- Its clock is ``time.monotonic() + CLOCK_OFFSET`` (seconds).
- Declares its liveliness token ``fedlab/default/LAB/NAME`` after its queryable and
  publisher (peers query it as soon as the token appears).
- Serves ``fedlab/default/LAB/NAME/sync``: reads ``t2`` when a query arrives; an 8-byte
  request holding a finite ``t1`` gets the 64-byte reply (t1, t2, x, y, heading, vx, vy,
  omega; float64 little-endian) on the query's key; anything else gets no reply. Every
  query is released at once.
- Publishes 56-byte pose samples (its clock, then the pose) at 20 Hz.
- Once a second prints a JSON line: its clock and the host's monotonic clock read
  together, requests served and dropped.
- Stops after DURATION seconds, or on SIGTERM; undeclares everything and closes the
  session; exit code 0.
"""

import json
import signal
import struct
import sys
import time

import zenoh

REQUEST = struct.Struct("<d")
REPLY = struct.Struct("<8d")
POSE = struct.Struct("<7d")
POSE_RATE = 20.0


def main(argv):
    endpoint, agent, clock_offset, duration = argv[1], argv[2], float(argv[3]), float(argv[4])
    key = f"fedlab/default/{agent}"

    def now():
        return time.monotonic() + clock_offset

    stopping = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    counts = {"served": 0, "dropped": 0}

    def heading(t):
        return 0.2 * ((t % 20.0) / 20.0)  # a slow ramp, rad

    def on_query(query):
        t2 = now()  # on arrival
        try:
            data = query.payload.to_bytes() if query.payload is not None else b""
            if len(data) != REQUEST.size:
                counts["dropped"] += 1
                return
            (t1,) = REQUEST.unpack(data)
            if not abs(t1) < float("inf"):  # NaN or infinity
                counts["dropped"] += 1
                return
            reply = REPLY.pack(t1, t2, 0.5, 1.5, heading(t2), 0.0, 0.0, 0.01)
            query.reply(query.key_expr, reply)
            counts["served"] += 1
        finally:
            query.drop()  # release it, or the querier waits for its timeout

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        # The token last (docs/protocol.md): peers query an agent as soon as it appears.
        queryable = session.declare_queryable(f"{key}/sync", on_query)
        publisher = session.declare_publisher(f"{key}/pose")
        token = session.liveliness().declare_token(key)
        end = time.monotonic() + duration
        next_pose = next_print = time.monotonic()
        while not stopping and time.monotonic() < end:
            if time.monotonic() >= next_pose:
                t = now()
                publisher.put(POSE.pack(t, 0.5, 1.5, heading(t), 0.0, 0.0, 0.01))
                next_pose += 1.0 / POSE_RATE
            if time.monotonic() >= next_print:
                host = time.monotonic()
                print(
                    json.dumps({"clock": host + clock_offset, "host": host, **counts}), flush=True
                )
                next_print += 1.0
            time.sleep(max(0.0, min(next_pose, next_print) - time.monotonic()))
        token.undeclare()
        queryable.undeclare()
        publisher.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
