"""Bare Zenoh pong: echo every sample on KEY/ping back on KEY/pong, with the arrival
time (CLOCK_MONOTONIC, ns, 8 bytes little-endian) appended, so the pinger on the same
host measures the one-way latency as well as the round trip. No fedlab imports.

Usage: python zenoh_pong.py ENDPOINT KEY SECONDS
"""

import sys
import time

import zenoh


def main() -> None:
    endpoint, key, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/unicast/lowlatency", "false")  # as fedlab's nodes
    conf.insert_json5("transport/unicast/qos/enabled", "true")
    with zenoh.open(conf) as session:
        pub = session.declare_publisher(f"{key}/pong", express=True)

        def echo(sample: zenoh.Sample) -> None:
            arrived = time.monotonic_ns()
            pub.put(sample.payload.to_bytes() + arrived.to_bytes(8, "little"))

        sub = session.declare_subscriber(
            f"{key}/ping", zenoh.handlers.Callback(echo, indirect=False)
        )
        print("ready", flush=True)
        time.sleep(seconds)
        sub.undeclare()
        pub.undeclare()


if __name__ == "__main__":
    main()
