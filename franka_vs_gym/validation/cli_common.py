"""Arguments shared by ``franka-vs compare``, ``diagnose`` and ``fit``."""

from __future__ import annotations

import argparse

from franka_vs_gym.validation.signals import CleanSettings


def add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="measurement log: CSV or NPZ (with optional <log>.json sidecar), or a Gaz et al. "
                                    "2019 text folder")
    parser.add_argument("--model", metavar="FILE", default=None,
                        help="calibrated model file (JSON) to compare; default: the FER with the log's declared tool")
    parser.add_argument("--rigid-body", action="store_true",
                        help="start from the model without any joint friction (rigid-body model)")
    parser.add_argument("--cutoff", type=float, default=CleanSettings.cutoff,
                        help=f"zero-phase low-pass cutoff for q and dq, Hz (default {CleanSettings.cutoff})")
    parser.add_argument("--rate", type=float, default=CleanSettings.rate,
                        help=f"resampling rate, Hz (default {CleanSettings.rate:.0f})")
    parser.add_argument("--report", metavar="DIR", default=None,
                        help="write a Markdown report with figures into DIR")
    parser.add_argument("--force", action="store_true", help="overwrite existing output files")
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")


def settings_from(args: argparse.Namespace) -> CleanSettings:
    return CleanSettings(rate=args.rate, cutoff=args.cutoff)
