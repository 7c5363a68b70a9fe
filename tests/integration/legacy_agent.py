"""A legacy agent as the paper's platforms had one: plain UDP sockets, no fedlab code.

    python tests/integration/legacy_agent.py PORT BRIDGE_HOST:BRIDGE_PORT CLOCK_OFFSET DURATION

- Its clock is ``time.monotonic() + CLOCK_OFFSET`` (seconds).
- One socket bound to 127.0.0.1:PORT. Every 100 ms it sends an 8-byte request
  (``t1``, float64 little-endian) to the bridge; it answers every 8-byte request with a
  64-byte reply (``t1`` echoed, ``t2`` read on arrival, then x, y, heading, vx, vy,
  omega) at once.
- From each 64-byte reply to one of its own requests it computes the paper's
  ``offset = t2 - (t1 + t3) / 2`` (Eq. 4) and ``delay = (t3 - t1) / 2`` (Eq. 3) and
  keeps the median of the last 50 (each offset is off by at most its delay, so the
  median is off by at most the largest of them, ``delay_max``).
- Once a second it prints a JSON line: its clock and the host's monotonic clock read
  together, the median offset and delay, the number of samples, the requests it
  served, the addresses they came from, the last pose it received.
- Stops after DURATION seconds, or on SIGTERM, with exit code 0.
"""

import json
import math
import signal
import socket
import struct
import sys
import time

REQUEST = struct.Struct("<d")
REPLY = struct.Struct("<8d")
POSE = (1.25, -0.5, 0.3, 0.0, 0.0, 0.0)  # x, y, heading, vx, vy, omega: standing still
PERIOD = 0.1
KEEP = 50


def median(values):
    ordered = sorted(values)
    n = len(ordered)
    if n == 0:
        return None
    mid = n // 2
    return ordered[mid] if n % 2 else (ordered[mid - 1] + ordered[mid]) / 2.0


def main(argv):
    port = int(argv[1])
    bridge_host, _, bridge_port = argv[2].rpartition(":")
    bridge = (bridge_host, int(bridge_port))
    clock_offset = float(argv[3])
    duration = float(argv[4])

    def now():
        return time.monotonic() + clock_offset

    stopping = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    pending = {}  # t1 -> None, requests not yet answered
    offsets, delays = [], []
    samples = served = malformed = 0
    sources = set()  # host:port of every request received
    received_pose = None
    end = time.monotonic() + duration
    next_request = time.monotonic()
    next_print = time.monotonic() + 1.0
    while not stopping and time.monotonic() < end:
        if time.monotonic() >= next_request:
            t1 = now()
            pending[t1] = None
            sock.sendto(REQUEST.pack(t1), bridge)
            for old in [t for t in pending if t1 - t > 1.0]:
                del pending[old]  # given up
            next_request += PERIOD
        if time.monotonic() >= next_print:
            host = time.monotonic()
            line = {
                "clock": host + clock_offset,
                "host": host,
                "offset": median(offsets),
                "delay": median(delays),
                "delay_max": max(delays, default=math.nan),
                "samples": samples,
                "served": served,
                "malformed": malformed,
                "pose": received_pose,
                "request_sources": sorted(sources),
            }
            print(json.dumps(line), flush=True)
            next_print += 1.0
        sock.settimeout(max(0.0005, min(next_request, next_print) - time.monotonic()))
        try:
            data, addr = sock.recvfrom(2048)
        except TimeoutError:
            continue
        t_arrival = now()  # t2 for a request, t3 for a reply
        if len(data) == REQUEST.size:
            (t1,) = REQUEST.unpack(data)
            if math.isfinite(t1):
                sock.sendto(REPLY.pack(t1, t_arrival, *POSE), addr)
                served += 1
                sources.add(f"{addr[0]}:{addr[1]}")
            else:
                malformed += 1
        elif len(data) == REPLY.size:
            values = REPLY.unpack(data)
            t1, t2 = values[0], values[1]
            if t1 not in pending or not all(math.isfinite(v) for v in values):
                malformed += 1
                continue
            del pending[t1]
            offsets.append(t2 - (t1 + t_arrival) / 2.0)  # Eq. 4: bridge's t2 minus own clock
            delays.append((t_arrival - t1) / 2.0)  # Eq. 3
            del offsets[:-KEEP], delays[:-KEEP]
            samples += 1
            received_pose = list(values[2:])
        else:
            malformed += 1
    sock.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
