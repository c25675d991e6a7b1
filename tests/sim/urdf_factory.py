"""URDFs written by the tests: serial arms of any number of links, and ill-posed variants."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _inertial(mass: float, com, inertia, rpy=(0.0, 0.0, 0.0)) -> str:
    ixx, iyy, izz, ixy, ixz, iyz = (float(v) for v in inertia)
    mass, com, rpy = float(mass), [float(v) for v in com], [float(v) for v in rpy]
    return (f'<inertial><mass value="{mass!r}"/><origin xyz="{com[0]!r} {com[1]!r} {com[2]!r}" '
            f'rpy="{rpy[0]!r} {rpy[1]!r} {rpy[2]!r}"/><inertia ixx="{ixx!r}" ixy="{ixy!r}" ixz="{ixz!r}" '
            f'iyy="{iyy!r}" iyz="{iyz!r}" izz="{izz!r}"/></inertial>')


def serial_arm(n: int, name: str = "arm", gripper: bool = False, effort: float | None = None,
               bad_link: dict | None = None) -> str:
    """A URDF of ``n`` revolute joints (axes z, y, y, z, y, z, ... from the base), links 0.25 m
    long with off-axis centres of mass and full inertia tensors, damping and friction on each
    joint, a visual mesh that exists nowhere, a fixed tool link, and with ``gripper`` a
    prismatic finger beyond the tool. ``bad_link`` = ``{"link": k, "mass": m, "inertia": (6,)}``
    replaces link k's inertial. Effort limits default to 80, 70, ... N m (at least 10)."""
    rng = np.random.default_rng(n)
    axes = ["0 0 1", "0 1 0", "0 1 0", "0 0 1", "0 1 0", "0 0 1", "0 1 0"]
    links = ['<link name="base_link"><visual><geometry><mesh filename="package://nowhere/base.stl"/></geometry></visual>'
             '<inertial><mass value="4.0"/><origin xyz="0 0 0.05"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" '
             'iyz="0" izz="0.02"/></inertial></link>']
    joints = []
    for k in range(n):
        mass = 3.0 - 2.0 * k / max(n, 1)
        d = rng.uniform(0.005, 0.02, 3)
        inertia = (d[1] + d[2], d[0] + d[2], d[0] + d[1], 0.1 * d[0], -0.05 * d[1], 0.02 * d[2])  # PD, triangle holds
        inertial = _inertial(mass, (0.01 * (k % 2), 0.0, 0.12), inertia, rpy=(0.05 * k, 0.0, 0.1))
        if bad_link and bad_link["link"] == k:
            inertial = _inertial(bad_link["mass"], (0, 0, 0.1), bad_link["inertia"]) if bad_link["mass"] is not None else ""
        links.append(f'<link name="link{k + 1}">{inertial}<visual><geometry><mesh filename="package://nowhere/l{k}.stl"/>'
                     '</geometry></visual><collision><geometry><cylinder radius="0.04" length="0.25"/></geometry>'
                     '</collision></link>')
        limit = effort if effort is not None else max(80.0 - 10.0 * k, 10.0)
        parent = "base_link" if k == 0 else f"link{k}"
        joints.append(f'<joint name="joint{k + 1}" type="revolute"><parent link="{parent}"/><child link="link{k + 1}"/>'
                      f'<origin xyz="0 0 {0.1 if k == 0 else 0.25}" rpy="0 0 0"/><axis xyz="{axes[k % len(axes)]}"/>'
                      f'<limit lower="-2.6" upper="2.6" effort="{limit!r}" velocity="2.0"/>'
                      f'<dynamics damping="{0.3 + 0.1 * k!r}" friction="{0.05 * (k + 1)!r}"/></joint>')
    links.append('<link name="tool"/>')
    joints.append(f'<joint name="tool_joint" type="fixed"><parent link="link{n}"/><child link="tool"/>'
                  '<origin xyz="0 0 0.1"/></joint>')
    if gripper:
        links.append('<link name="finger">' + _inertial(0.05, (0, 0, 0.02), (1e-5, 1e-5, 1e-5, 0, 0, 0)) + '</link>')
        joints.append('<joint name="finger_joint" type="prismatic"><parent link="tool"/><child link="finger"/>'
                      '<axis xyz="1 0 0"/><limit lower="0" upper="0.04" effort="20" velocity="0.2"/></joint>')
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n' + "\n".join(links + joints) + "\n</robot>\n"


def write(path: Path, text: str) -> str:
    path.write_text(text)
    return str(path)
