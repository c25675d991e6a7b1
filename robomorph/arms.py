"""``python -m robomorph.arms`` (or ``robomorph arms``): your own arms, from a URDF or an MJCF.

``robomorph arms add NAME --urdf robot.urdf`` registers an arm in the user folder
(``$ROBOMORPH_ARMS``, else ``$XDG_DATA_HOME/robomorph/arms``, else ``~/.local/share/robomorph/arms``),
never in the installed package; ``robomorph arms list`` shows the shipped and the user arms;
``robomorph arms remove NAME`` removes a user arm. The door only; the machinery is
:mod:`robomorph.sim.user_arms`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import run_command

SUBCOMMANDS = ("add", "list", "remove")


def _names(text: str) -> tuple[str, ...]:
    return tuple(c.strip() for c in text.split(",") if c.strip())


def _numbers(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(c) for c in text.split(",") if c.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of numbers (N m)") from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.arms", description=__doc__.split("\n")[0],
                                epilog="python -m robomorph.arms add --help | list --help | remove --help")
    p.add_argument("subcommand", choices=SUBCOMMANDS, help="add an arm, list the arms, remove a user arm")
    return p


def build_add_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.arms add",
                                description="register an arm from its URDF (or MJCF) in the user folder")
    p.add_argument("name", help="the arm's name for --robot / --arm / Predictor.from_arm")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--urdf", help="the robot's URDF (inertials, limits, <dynamics>; meshes are not needed)")
    src.add_argument("--mjcf", help="the robot's MJCF (compiled with its meshes; kept without geometry)")
    p.add_argument("--base-link", help="URDF: the link fixed to the world (default: the root link)")
    p.add_argument("--ee-link", help="the end-effector link (URDF) or body (MJCF); default: the one deepest link, or "
                   "the MJCF's last driven joint's body")
    p.add_argument("--joints", type=_names, help="the driven joints, comma-separated, base first (default: the movable "
                   "joints from --base-link to --ee-link; others are welded)")
    p.add_argument("--torque-limits", type=_numbers, metavar="N1,N2,...",
                   help="each driven joint's torque limit [N m] (default: the URDF's effort limits / MJCF's motor ranges)")
    p.add_argument("--overwrite", action="store_true", help="replace a user arm of the same name")
    return p


def build_list_parser() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(prog="python -m robomorph.arms list", description="the shipped and the user arms")


def build_remove_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.arms remove", description="remove a user arm")
    p.add_argument("name", help="a user arm's name (shipped arms cannot be removed)")
    return p


def run_add(a: argparse.Namespace) -> int:
    from robomorph.sim import arms, user_arms  # noqa: PLC0415  (MuJoCo only when an arm is added)

    req = user_arms.ArmRequest(a.name, a.urdf or a.mjcf, "urdf" if a.urdf else "mjcf", a.base_link, a.ee_link,
                               a.joints, a.torque_limits)
    arm = user_arms.add(req, overwrite=a.overwrite)
    print(f"{arm.name}: {arm.n_joint} joints ({', '.join(arm.joint_names)}), end effector {arm.hand}, torque limits "
          f"{', '.join(f'{v:g}' for v in arm.torque_limits)} N m; registered in {arms.user_folder()}")
    print(f"next: robomorph ingest --rosbag BAG --layout {arm.name} --steps 200 --out data/{arm.name}.zarr, then "
          f"robomorph evaluate --arm {arm.name} --data data/{arm.name}.zarr")
    return 0


def run_list(a: argparse.Namespace) -> int:
    from robomorph.sim import arms, user_arms  # noqa: PLC0415

    rows = user_arms.listing()
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        tail = f"  {r['source']}" if r["source"] else ""
        print(f"{r['name']:{width}s}  {r['kind']:7s}  {r['joints']} joints  {r['title']}{tail}")
    print(f"user arms: {arms.user_folder()}")
    return 0


def run_remove(a: argparse.Namespace) -> int:
    from robomorph.sim import user_arms  # noqa: PLC0415

    print(f"removed {a.name} ({user_arms.remove(a.name)})")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in SUBCOMMANDS:
        build_parser().parse_args(argv)  # --help (exit 0), or the usage error naming the choices (exit 2)
        return 2
    sub, rest = argv[0], argv[1:]
    parser = {"add": build_add_parser, "list": build_list_parser, "remove": build_remove_parser}[sub]()
    args = parser.parse_args(rest)
    return run_command(lambda: {"add": run_add, "list": run_list, "remove": run_remove}[sub](args))


if __name__ == "__main__":
    sys.exit(main())
