#!/usr/bin/env python
"""Canopy SLAM launcher: `python launch.py --dataset euroc`.

Starts the actors (source, enhancement, tracking, local mapping) as separate
processes, prints progress and a summary, and writes the results folder.
"""
from __future__ import annotations

import argparse
import signal
import sys
import warnings

from shared.errors import CanopyError, InputWarning


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows a flag's default only when it has a real one the help text does not already name."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default in (None, False, argparse.SUPPRESS) or "default" in text:
            return text
        return super()._get_help_string(action)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    if issubclass(category, InputWarning):
        print(f"warning: {message}", file=sys.stderr)  # one line naming the input, no source location
    else:
        _default_show_warning(message, category, filename, lineno, file, line)


_default_show_warning = warnings.showwarning


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="launch.py",
        description="Stereo visual SLAM for low light and haze. With no --path, runs on the "
                    "snippet of the dataset bundled in data/.",
        formatter_class=_HelpFormatter)
    p.add_argument("--dataset", choices=("euroc", "kitti", "folder", "synthetic"), default="euroc",
                   help="dataset layout: EuRoC ASL folder (mav0/), KITTI odometry sequence, a folder "
                        "with left/, right/ and calib.yaml, or a generated orchard sequence (see --preset)")
    p.add_argument("--preset", default=None,
                   help="with --dataset synthetic: day-loop (default), dusk-loop, haze-row or dark-rows; "
                        "generated once into cache/synthetic/ (with --max-frames N only N frames)")
    p.add_argument("--seed", type=int, default=0, help="with --dataset synthetic: the generator's seed")
    p.add_argument("--path", default=None,
                   help="dataset folder; default: the bundled EuRoC V1_01 / KITTI 06 snippet in data/")
    p.add_argument("--config", default=None,
                   help="parameter YAML (sections runtime, enhancement, tracking, mapping); "
                        "default: configs/<dataset>.yaml")
    p.add_argument("--out", default=None, help="results folder; default: results/<dataset>-<time>/")
    p.add_argument("--clock", choices=("lockstep", "realtime"), default=None,
                   help="lockstep: frames in order, none dropped, each local-map update applied before a fixed later "
                        "frame (runtime.map_update_lag_frames; deterministic); realtime: "
                        "frames arrive at the dataset rate and late frames are dropped and counted "
                        "(default from the config: lockstep)")
    p.add_argument("--max-frames", type=int, default=None, help="process only the first N frames")
    p.add_argument("--enhance", choices=("none", "he", "clahe", "afe", "agri", "auto"), default=None,
                   help="image enhancement before feature extraction (default from the config)")
    p.add_argument("--lines", action=argparse.BooleanOptionalAction, default=None,
                   help="track and bundle-adjust line segments (FLD + LBD) as well as ORB points "
                        "(default from the config: off)")
    p.add_argument("--loop", action=argparse.BooleanOptionalAction, default=None,
                   help="loop closing: place recognition, pose-graph correction (default from the config: on)")
    p.add_argument("--save-map", default=None, metavar="PATH",
                   help="write the final map (keyframes, landmarks, descriptors, covisibility) to PATH "
                        "(versioned msgpack, canopy.loop.map_io)")
    p.add_argument("--load-map", default=None, metavar="PATH",
                   help="start from a map written by --save-map: the first frames are relocalised in it "
                        "(keyframe-database query + stereo PnP), then the map is extended with this run's "
                        "keyframes (save the union with --save-map); with --localize it is only tracked in")
    p.add_argument("--localize", action="store_true",
                   help="with --load-map: track in the loaded map without adding keyframes or changing it")
    p.add_argument("--sensor", choices=("stereo", "mono"), default=None,
                   help="stereo pairs, or the left image only (monocular: two-view initialisation, "
                        "a map without metric scale, Sim(3)-aligned ATE in metrics.json); default from "
                        "the config: stereo")
    p.add_argument("--inspect", default=None, metavar="ENDPOINT",
                   help="publish every event on this ZeroMQ endpoint for remote clients and answer "
                        "requests on the next port, e.g. tcp://127.0.0.1:5560 (see tools/watch_run.py); "
                        "a non-loopback address needs --inspect-keys")
    p.add_argument("--inspect-keys", default=None, metavar="DIR",
                   help="CURVE keys for --inspect (server key pair, allowed clients' public keys in "
                        "DIR/authorized/), made by tools/make_inspect_keys.py")
    p.add_argument("--record", nargs="?", const="", default=None, metavar="PATH",
                   help="write an .mcap recording for Foxglove (poses, images, map points and lines); "
                        "without PATH: <out>/run.mcap")
    p.add_argument("--foxglove", nargs="?", const="127.0.0.1:8765", default=None, metavar="HOST:PORT",
                   help="serve the run live to the Foxglove app (poses, images, map, events) over its "
                        "WebSocket protocol; loopback only (default 127.0.0.1:8765); needs the "
                        "foxglove-sdk package: pip install '.[foxglove]'")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    warnings.showwarning = _show_warning
    if args.max_frames is not None and args.max_frames < 1:
        print("error: --max-frames must be at least 1", file=sys.stderr)
        return 2
    if args.preset is not None and args.dataset != "synthetic":
        print("error: --preset only applies to --dataset synthetic", file=sys.stderr)
        return 2
    try:
        from canopy.app import run_slam
        result = run_slam(args.dataset, path=args.path, config=args.config, out=args.out, clock=args.clock,
                          max_frames=args.max_frames, enhance=args.enhance, inspect=args.inspect,
                          progress=not args.quiet, preset=args.preset, seed=args.seed, lines=args.lines,
                          record=args.record, inspect_keys=args.inspect_keys, loop=args.loop,
                          save_map=args.save_map, sensor=args.sensor, load_map=args.load_map,
                          localize=args.localize, foxglove=args.foxglove)
    except CanopyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(result.text)
    if not result.outcome.ok:
        print(f"error: run ended early: {result.outcome.reason}; results so far are in {result.out_dir}",
              file=sys.stderr)
        return 1
    return 0


def answer_ctrl_c() -> None:
    """Ctrl-C stops a run cleanly (the supervisor keeps what was computed), whatever SIGINT
    disposition this process inherited: Python leaves SIGINT ignored when its parent ignored it
    (a shell's background job, a test runner), and a blocked SIGINT stays blocked across exec."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])


if __name__ == "__main__":
    answer_ctrl_c()
    sys.exit(main())
