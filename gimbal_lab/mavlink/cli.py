"""``gimbal-lab gimbal-device``: the lab's gimbal as a MAVLink gimbal device on a UDP or serial link.

Registered in :mod:`gimbal_lab.cli` through :func:`add_parsers`. This module imports neither
pymavlink nor the simulation until the command runs, so the command line works without the
``[mavlink]`` extra (the command then says what to install).
"""

from __future__ import annotations

import argparse
import math
import sys

_BODIES = ("still", "hover", "vibration", "flying")
# LinkEffects' bounds (gimbal_lab.mavlink.device, MAX_STATUS_RATE_HZ and MAX_LATENCY_S; a test pins
# them equal), written here so that --help works without pymavlink
_MAX_STATUS_RATE_HZ = 1000.0
_MAX_LATENCY_S = 10.0


def _one_line_errors(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Make ``parser`` report a bad argument as one line on stderr and exit 2 (no usage block)."""
    def error(message: str):
        print(f"{parser.prog}: error: {message}", file=sys.stderr)
        sys.exit(2)

    parser.error = error
    return parser


def add_parsers(sub) -> None:
    """Register ``gimbal-lab gimbal-device`` on an argparse sub-parser set."""
    p = sub.add_parser(
        "gimbal-device", help="run the lab's simulated gimbal as a MAVLink gimbal device (Gimbal Protocol v2)",
        description="Run the lab's gimbal (yaw-roll-pitch kinematics, axis dynamics and rate loops on a drone "
                    "body) as a MAVLink 2 gimbal device: HEARTBEAT at 1 Hz, GIMBAL_DEVICE_INFORMATION on "
                    "request, GIMBAL_DEVICE_SET_ATTITUDE in (rates or attitude), GIMBAL_DEVICE_ATTITUDE_STATUS out, "
                    "and a gimbal manager on the same component (GIMBAL_MANAGER_INFORMATION, GIMBAL_MANAGER_STATUS, "
                    "MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE and _PITCHYAW, GIMBAL_MANAGER_SET_ATTITUDE and _PITCHYAW). "
                    "Real time by default; --lockstep advances only on the driver's step command "
                    "(docs/design.md, \"MAVLink gimbal\").",
        epilog="Example: gimbal-lab gimbal-device --listen udpin:127.0.0.1:14555 --latency-s 0.02 --loss 0.05")
    _one_line_errors(p)
    p.add_argument("--listen", default="udpin:127.0.0.1:14555", metavar="ADDRESS",
                   help="udpin:HOST:PORT, udpout:HOST:PORT, a serial device (/dev/ttyUSB0) or a pyserial URL "
                        "(default udpin:127.0.0.1:14555)")
    p.add_argument("--baud", type=int, default=115200, help="serial speed, bit/s (default 115200)")
    p.add_argument("--system-id", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--component-id", type=int, default=154, help="MAVLink component id (default 154, MAV_COMP_ID_GIMBAL)")
    p.add_argument("--lockstep", action="store_true", help="advance only on the driver's step command")
    p.add_argument("--status-rate-hz", type=float, default=20.0,
                   help=f"attitude status rate, Hz, in (0, {_MAX_STATUS_RATE_HZ:g}] (default 20)")
    p.add_argument("--latency-s", type=float, default=0.0,
                   help=f"one-way latency of statuses and commands, s, in [0, {_MAX_LATENCY_S:g}] (default 0)")
    p.add_argument("--quantum-deg", type=float, default=0.0,
                   help="resolution of the reported angles, degrees (e.g. 0.1; default 0: none)")
    p.add_argument("--loss", type=float, default=0.0, help="probability that a status is lost, in [0, 1) (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the losses and of the body's motion (default 0)")
    p.add_argument("--commanded-only", action="store_true",
                   help="report the commanded attitude instead of the measured one (a gimbal without feedback)")
    p.add_argument("--max-rate-deg-s", type=float, default=None,
                   help="largest axis rate, degrees/s (default: 3 rad/s, about 172)")
    p.add_argument("--body", choices=_BODIES, default="still",
                   help="the drone body's motion (default still; the others are drawn for the whole --duration-s "
                        "at start, about 2 s per simulated second)")
    p.add_argument("--body-yaw-deg", type=float, default=0.0, help="the still body's heading, degrees left of North "
                                                                   "(the lab's yaw; default 0)")
    p.add_argument("--duration-s", type=float, default=3600.0,
                   help="simulated time the device can run, s (default 3600)")
    p.add_argument("--no-manager", action="store_true",
                   help="no gimbal manager on the device's component (a bare gimbal device behind an autopilot)")
    p.add_argument("--signing-key-file", default=None, metavar="FILE",
                   help="MAVLink 2 signing key (32 raw bytes or 64 hex characters): sign what the device sends and "
                        "refuse unsigned or wrongly signed packets (counted); default: no signing")
    p.set_defaults(func=_gimbal_device_command, _parser=p)


def _gimbal_device_command(args, parser) -> int:
    def bad(message: str) -> int:
        parser.error(message)
        return 2  # not reached: parser.error exits

    for name in ("status_rate_hz", "latency_s", "quantum_deg", "loss", "duration_s", "body_yaw_deg"):
        if not math.isfinite(getattr(args, name)):
            return bad(f"--{name.replace('_', '-')} must be finite, got {getattr(args, name)}")
    if not 0 < args.status_rate_hz <= _MAX_STATUS_RATE_HZ:
        return bad(f"--status-rate-hz must be in (0, {_MAX_STATUS_RATE_HZ:g}], got {args.status_rate_hz:g}")
    if not 0 <= args.latency_s <= _MAX_LATENCY_S:
        return bad(f"--latency-s must be in [0, {_MAX_LATENCY_S:g}], got {args.latency_s:g}")
    if args.quantum_deg < 0:
        return bad(f"--quantum-deg must be >= 0, got {args.quantum_deg:g}")
    if not 0 <= args.loss < 1:
        return bad(f"--loss must be in [0, 1), got {args.loss:g}")
    if args.seed < 0:
        return bad(f"--seed must be >= 0, got {args.seed}")
    if args.duration_s <= 0:
        return bad(f"--duration-s must be > 0, got {args.duration_s:g}")
    if args.baud <= 0:
        return bad(f"--baud must be > 0, got {args.baud}")
    for name in ("system_id", "component_id"):
        if not 1 <= getattr(args, name) <= 255:
            return bad(f"--{name.replace('_', '-')} must be in 1..255, got {getattr(args, name)}")
    if args.max_rate_deg_s is not None and not (math.isfinite(args.max_rate_deg_s) and args.max_rate_deg_s > 0):
        return bad(f"--max-rate-deg-s must be > 0, got {args.max_rate_deg_s:g}")
    if args.body != "still" and args.body_yaw_deg != 0:
        return bad("--body-yaw-deg applies to the still body only")
    try:
        import pymavlink  # noqa: F401
        import serial  # noqa: F401
    except ModuleNotFoundError as exc:
        print(f"{parser.prog}: needs {exc.name}: pip install 'gimbal-lab[mavlink]'", file=sys.stderr)
        return 1

    from ..platform import BodyMotion
    from .device import DEFAULT_MAX_RATE_RAD_S, LinkEffects, SimulatedGimbalDevice, simulated_gimbal
    from .link import open_link
    from .signing import read_key

    key = None
    if args.signing_key_file is not None:
        try:
            key = read_key(args.signing_key_file)
        except ValueError as exc:
            return bad(f"--signing-key-file: {exc}")

    if args.body == "still":
        body = BodyMotion(yaw_rad=math.radians(args.body_yaw_deg))
    elif args.body == "flying":
        body = BodyMotion.flying(args.seed)
    else:
        body = BodyMotion.hover(args.seed, vibration=args.body == "vibration")
    effects = LinkEffects(status_rate_hz=args.status_rate_hz, latency_s=args.latency_s,
                          quantum_rad=math.radians(args.quantum_deg), loss=args.loss, seed=args.seed,
                          commanded_only=args.commanded_only)
    try:
        link = open_link(args.listen, args.baud)
    except ValueError as exc:
        return bad(f"--listen: {exc}")
    except OSError as exc:
        return bad(f"--listen: {exc.strerror or exc}")
    device = None
    try:
        device = SimulatedGimbalDevice(
            link, simulated_gimbal(body=body, duration_s=args.duration_s), effects, lockstep=args.lockstep,
            system_id=args.system_id, component_id=args.component_id,
            max_rate_rad_s=math.radians(args.max_rate_deg_s) if args.max_rate_deg_s else DEFAULT_MAX_RATE_RAD_S,
            signing_key=key, manager=not args.no_manager)
        print(f"gimbal-device: system {args.system_id} component {args.component_id} on {args.listen}, "
              f"{'lock-step' if args.lockstep else 'real time'}, status {args.status_rate_hz:g} Hz, latency "
              f"{args.latency_s:g} s, quantum {args.quantum_deg:g}°, loss {args.loss:g} (seed {args.seed})"
              f"{', commanded only' if args.commanded_only else ''}, {args.body} body"
              f"{', signed' if key is not None else ''}{', no manager' if args.no_manager else ', manager on'}"
              f"; Ctrl-C stops", flush=True)
        reason = device.run()
    except KeyboardInterrupt:
        t = f" at {device.t_s:.3f} s simulated" if device is not None else ""
        counts = "0 statuses sent"
        if device is not None:
            counts = (f"{device.statuses_sent} statuses sent, {device.packets_dropped} packets dropped "
                      f"({device.packets_refused} refused for their signature)")
        print(f"gimbal-device: interrupted{t}; {counts}", flush=True)
        return 130
    finally:
        link.close()
    print(f"gimbal-device: {reason} at {device.t_s:.3f} s simulated; {device.statuses_sent} statuses sent, "
          f"{device.statuses_lost} lost; {device.packets_dropped} packets dropped "
          f"({device.packets_refused} refused for their signature)", flush=True)
    return 0
