"""A revolute serial chain to and from URDF, brand-free.

URDF is how ROS, MoveIt and Pinocchio describe a robot: links joined by joints, each
joint placed by an ``<origin xyz rpy>`` on its parent link and turning about an
``<axis xyz>`` in its own frame. That is exactly :class:`~spherecal.core.kinematics.SerialChain`
(``placements[i]`` is joint i's origin, ``axes[i]`` its axis, ``flange_placement`` a
fixed joint to the flange link), except for the unit: **URDF is in metres**, a
SerialChain in millimetres. Both functions here convert.

* :func:`chain_to_urdf` writes a chain as URDF text: links ``base_link``, ``link_1`` ...
  ``link_n`` and the flange link (``tool0``), revolute joints ``joint_1`` ... ``joint_n``
  and a fixed joint ``joint_n-tool0``, with every number written with 17 significant
  digits so that reading it back reproduces the chain to rounding (1e-12 mm on an
  industrial arm). The joint values are the chain's (the serial model's convention,
  which for a robot with coupled axes is not the controller's: the plugin says how).
* :func:`read_urdf_chain` / :func:`chain_from_urdf` read the serial chain between two
  links of any URDF through Pinocchio (``buildModelFromUrdf``): fixed joints between
  the revolute ones are folded into the next joint's placement (or into the flange
  placement), so URDFs with tool frames, mounting plates or ``world`` links read as
  well as ours.

URDF rpy (roll, pitch, yaw) are fixed-axis rotations about x, then y, then z:
``R = Rz(yaw) Ry(pitch) Rx(roll)``.

The numerical inverse kinematics of a chain (:func:`chain_inverse_kinematics`) lives
here too, next to the forward model it inverts: a robot plugin that applies a
calibrated chain read from URDF needs it, and so does a robot type described only by
its URDF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spherecal.core.errors import InputError
from spherecal.core.kinematics import SerialChain

#: Millimetres per metre (divide to write, multiply to read: both correctly rounded for round numbers).
_MM_PER_M = 1000.0


# ---------------------------------------------------------------------------------------
# small helpers
# ---------------------------------------------------------------------------------------
def rpy_from_matrix(R) -> tuple[float, float, float]:
    """URDF (roll, pitch, yaw) in rad of a rotation matrix, ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    Robust at every pitch, including the gimbal lock at +-90 deg: yaw is taken first,
    then roll and pitch come from the remaining rotation ``Ry(pitch) Rx(roll)``, whose
    entries used are all of unit size, so the angles reproduce ``R`` to rounding."""
    R = np.asarray(R, dtype=float)
    yaw = math.atan2(R[1, 0], R[0, 0])
    c, s = math.cos(yaw), math.sin(yaw)
    M = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ R  # Rz(-yaw) R = Ry(pitch) Rx(roll)
    pitch = math.atan2(-M[2, 0], M[0, 0])
    roll = math.atan2(-M[1, 2], M[1, 1])
    return roll, pitch, yaw


def matrix_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation matrix of URDF (roll, pitch, yaw) in rad: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def fold_zero_offsets(chain: SerialChain, zero_offsets_rad) -> SerialChain:
    """The chain whose joint i reads 0 where ``chain``'s reads ``zero_offsets_rad[i]``:
    ``placement_i <- placement_i @ Rot(axis_i, dq_i)``. A calibrated chain carries its
    joint zero offsets this way, so that it takes the same joint values as the nominal
    one (``chain.flange_matrices(q + dq) == folded.flange_matrices(q)``)."""
    dq = np.asarray(zero_offsets_rad, dtype=float).reshape(-1)
    if dq.shape != (chain.n_joints,):
        raise InputError(f"fold_zero_offsets: expected {chain.n_joints} offsets, got {dq.size}")
    P = chain.placements.copy()
    for i in range(chain.n_joints):
        P[i, :3, :3] = P[i, :3, :3] @ _axis_angle(chain.axes[i], dq[i])
    return SerialChain(P, chain.axes.copy(), chain.flange_placement.copy())


def _axis_angle(axis, angle: float) -> np.ndarray:
    """Rotation about the unit ``axis`` by ``angle`` (rad), Rodrigues."""
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    return np.array([
        [c + t * x * x, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, c + t * z * z],
    ])


def _num(x: float) -> str:
    """A float written so that it reads back exactly (at most 17 significant digits), no ``-0``."""
    x = float(x)
    return "0" if x == 0.0 else repr(x)  # Python's repr is the shortest string that reads back exactly


def _vec(v) -> str:
    return " ".join(_num(x) for x in v)


def _origin(T: np.ndarray) -> str:
    xyz = _vec(np.asarray(T[:3, 3]) / _MM_PER_M)
    rpy = _vec(rpy_from_matrix(T[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def _xml_text(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")


def _xml_comment(s: str) -> str:
    return s.replace("--", "- -")


# ---------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------
def chain_to_urdf(
    chain: SerialChain,
    robot_name: str,
    joint_names=None,
    flange_link: str = "tool0",
    base_link: str = "base_link",
    joint_limits_rad=None,
    comment: str | None = None,
    warning: str | None = None,
    joint_velocity_limits_rad_s=None,
) -> str:
    """The chain as URDF text, in **metres** (the chain is in mm).

    Links ``base_link``, ``link_1`` ... ``link_n``, ``flange_link``; revolute joints
    ``joint_names`` (default ``joint_1`` ... ``joint_n``), each with the ``<origin>`` of
    its placement and the ``<axis>`` of the chain; a fixed joint ``<last joint>-<flange
    link>`` carries the flange placement. Links have no inertia (Pinocchio and ROS read
    kinematics from such a file; add inertias elsewhere to simulate dynamics).

    ``joint_limits_rad``: (n, 2) lower and upper limits in the chain's joint convention
    (URDF requires limits on revolute joints); None writes -pi .. pi and says in the
    file that these are not the robot's limits. ``joint_velocity_limits_rad_s``: (n,)
    speeds; None writes 0 (unknown), as the effort always is. ``comment`` is added to
    the header comment (say where the geometry came from); ``warning``, when given, is
    its first line (a RED result's, :func:`spherecal.io.exporters.red_warning`)."""
    if not isinstance(chain, SerialChain):
        raise InputError(f"chain_to_urdf: expected a SerialChain, got {type(chain).__name__}")
    n = chain.n_joints
    names = [f"joint_{i}" for i in range(1, n + 1)] if joint_names is None else [str(j) for j in joint_names]
    if len(names) != n or len(set(names)) != n or any(not j for j in names):
        raise InputError(f"chain_to_urdf: expected {n} distinct non-empty joint names, got {names}")
    links = [base_link] + [f"link_{i}" for i in range(1, n + 1)] + [flange_link]
    if len(set(links)) != len(links):
        raise InputError(f"chain_to_urdf: link names must differ, got base {base_link!r}, flange {flange_link!r} "
                         f"and link_1 .. link_{n}")
    limits_given = joint_limits_rad is not None
    if limits_given:
        limits = np.asarray(joint_limits_rad, dtype=float)
        if limits.shape != (n, 2) or not np.all(np.isfinite(limits)) or np.any(limits[:, 0] >= limits[:, 1]):
            raise InputError(f"chain_to_urdf: joint_limits_rad must be ({n}, 2) finite (lower < upper), got "
                             f"{np.asarray(joint_limits_rad).tolist()}")
    else:
        limits = np.tile([-math.pi, math.pi], (n, 1))
    if joint_velocity_limits_rad_s is None:
        velocities = np.zeros(n)
    else:
        velocities = np.asarray(joint_velocity_limits_rad_s, dtype=float).reshape(-1)
        if velocities.shape != (n,) or not np.all(np.isfinite(velocities)) or np.any(velocities < 0):
            raise InputError(f"chain_to_urdf: joint_velocity_limits_rad_s must be {n} values >= 0")

    header = [
        f"{robot_name}: a revolute serial chain written by spherecal (spherecal.core.urdf.chain_to_urdf).",
        "Units: metres and radians, as every URDF (spherecal itself works in millimetres).",
        f"Joints {names[0]} .. {names[-1]}, base link {base_link}, flange frame {flange_link} "
        f"(fixed joint {names[-1]}-{flange_link}).",
        "Joint values are the serial model's: joint i turns link i about its axis relative to link i-1",
        "(for a robot with coupled axes this may differ from what its controller reports; see the",
        "robot plugin's documentation). Joint zero offsets are folded into the joint origins.",
    ]
    if not limits_given:
        header.append("Joint limits are placeholders (-pi .. pi), not the robot's ranges.")
    if joint_velocity_limits_rad_s is None:
        header.append("Effort and velocity limits are not stated (0).")
    header.append("Links carry no inertia: kinematics only.")
    if comment:
        header.extend(str(comment).splitlines())
    if warning:
        header.insert(0, str(warning))

    out = ['<?xml version="1.0"?>', "<!--"]
    out += [f"  {_xml_comment(line)}" for line in header]
    out += ["-->", f'<robot name="{_xml_text(robot_name)}">']
    for link in links:
        out.append(f'  <link name="{_xml_text(link)}"/>')
    for i in range(n):
        axis = chain.axes[i] / np.linalg.norm(chain.axes[i])
        out += [
            f'  <joint name="{_xml_text(names[i])}" type="revolute">',
            f'    <parent link="{_xml_text(links[i])}"/>',
            f'    <child link="{_xml_text(links[i + 1])}"/>',
            f"    {_origin(chain.placements[i])}",
            f'    <axis xyz="{_vec(axis)}"/>',
            f'    <limit lower="{_num(limits[i, 0])}" upper="{_num(limits[i, 1])}" effort="0" '
            f'velocity="{_num(velocities[i])}"/>',
            "  </joint>",
        ]
    out += [
        f'  <joint name="{_xml_text(names[-1])}-{_xml_text(flange_link)}" type="fixed">',
        f'    <parent link="{_xml_text(links[n])}"/>',
        f'    <child link="{_xml_text(flange_link)}"/>',
        f"    {_origin(chain.flange_placement)}",
        "  </joint>",
        "</robot>",
        "",
    ]
    return "\n".join(out)


def write_urdf(path, chain: SerialChain, robot_name: str, **kwargs) -> Path:
    """:func:`chain_to_urdf` into ``path`` (UTF-8); returns the path."""
    path = Path(path)
    path.write_text(chain_to_urdf(chain, robot_name, **kwargs), encoding="utf-8")
    return path


# ---------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class UrdfChain:
    """The serial chain read from a URDF between two links, with what the URDF says
    about its joints (names in order, limits in rad, velocity limits in rad/s)."""

    chain: SerialChain
    joint_names: tuple[str, ...]
    lower_rad: np.ndarray
    upper_rad: np.ndarray
    velocity_rad_s: np.ndarray
    source: str


def _looks_like_text(path_or_text) -> bool:
    return isinstance(path_or_text, str) and path_or_text.lstrip().startswith("<")


def read_urdf_chain(path_or_text, base_link: str, flange_link: str, joint_names=None) -> UrdfChain:
    """The revolute serial chain from link ``base_link`` to link ``flange_link`` of a URDF
    (a file path, or the URDF text itself when it starts with ``<``), through Pinocchio.

    Placements are converted to mm; fixed joints on the way fold into the next revolute
    joint's placement or into the flange placement. ``joint_names``, when given, must be
    the chain's revolute joints in order from base to flange. Raises
    :class:`~spherecal.core.errors.InputError` naming the file and the link or joint at fault:
    a file that is not URDF, a missing link, a flange link not downstream of the base
    link, a joint on the way that is not revolute (prismatic, planar, floating...)."""
    import pinocchio as pin

    if _looks_like_text(path_or_text):
        where, text = "URDF text", path_or_text
    else:
        where = str(path_or_text)
        try:
            text = Path(path_or_text).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"{where}: cannot read the URDF file ({getattr(exc, 'strerror', None) or exc})") from None
    import xml.etree.ElementTree as ET  # (here: reading a URDF is rare beside importing this module)

    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise InputError(f"{where}: not a URDF file (not well-formed XML: {exc})") from None
    if root.tag != "robot":
        raise InputError(f"{where}: not a URDF file (its root element is <{root.tag}>, URDF's is <robot>)")
    link_names = [e.get("name") for e in root.findall("link")]
    joint_types = {e.get("name"): e.get("type") for e in root.findall("joint")}
    for what, name in (("base_link", base_link), ("flange_link", flange_link)):
        if name not in link_names:
            shown = ", ".join(str(x) for x in link_names[:20]) + (" ..." if len(link_names) > 20 else "")
            raise InputError(f"{where}: no link named {name!r} ({what}); the file's links: {shown or 'none'}")
    try:
        model = pin.buildModelFromXML(text)
    except (ValueError, RuntimeError) as exc:
        raise InputError(f"{where}: Pinocchio cannot read this URDF ({str(exc).splitlines()[0]})") from None

    def body_frame(name: str):
        for fid, frame in enumerate(model.frames):
            if frame.name == name and frame.type == pin.FrameType.BODY:
                return fid, frame
        raise InputError(f"{where}: link {name!r} is not in Pinocchio's model of this URDF")  # pragma: no cover

    _, fb = body_frame(base_link)
    _, ff = body_frame(flange_link)
    # joints from the flange up to the base link's joint
    path = []
    j = ff.parentJoint
    while j != fb.parentJoint:
        if j == 0:
            raise InputError(
                f"{where}: link {flange_link!r} is not downstream of link {base_link!r}; the chain from "
                f"{base_link!r} to {flange_link!r} must follow the URDF's parent -> child joints"
            )
        path.append(j)
        j = model.parents[j]
    path.reverse()
    if not path:
        raise InputError(f"{where}: no moving joint between links {base_link!r} and {flange_link!r}")

    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    placements, axes, names, lower, upper, velocity = [], [], [], [], [], []
    for k, j in enumerate(path):
        name = model.names[j]
        jm = model.joints[j]
        urdf_type = joint_types.get(name, "?")
        S = np.array(data.joints[j].S).reshape(6, -1)  # motion subspace in the joint's frame: (v, w)
        if urdf_type not in ("revolute", "continuous") or jm.nv != 1 or np.linalg.norm(S[:3, 0]) > 1e-12:
            raise InputError(
                f"{where}: joint {name!r} between links {base_link!r} and {flange_link!r} is "
                f"{urdf_type!r}; a serial chain here takes revolute (or continuous) joints only, and "
                f"fixed joints in between"
            )
        axis = S[3:, 0] / np.linalg.norm(S[3:, 0])
        placement = np.array(model.jointPlacements[j].homogeneous)
        if k == 0:  # relative to the base link rather than to the joint the base link is on
            placement = np.linalg.inv(np.array(fb.placement.homogeneous)) @ placement
        placement[:3, 3] *= _MM_PER_M
        placements.append(placement)
        axes.append(axis)
        names.append(name)
        if jm.nq == 1:
            lower.append(float(model.lowerPositionLimit[jm.idx_q]))
            upper.append(float(model.upperPositionLimit[jm.idx_q]))
        else:  # continuous: no limits
            lower.append(-math.inf)
            upper.append(math.inf)
        velocity.append(float(model.velocityLimit[jm.idx_v]))
    flange = np.array(ff.placement.homogeneous)
    flange[:3, 3] *= _MM_PER_M
    if joint_names is not None:
        want = [str(x) for x in joint_names]
        if want != names:
            raise InputError(
                f"{where}: the revolute joints from {base_link!r} to {flange_link!r} are {names}; "
                f"the configuration expects {want}"
            )
    try:
        chain = SerialChain(np.array(placements), np.array(axes), flange)
    except ValueError as exc:  # pragma: no cover - Pinocchio gives proper placements
        raise InputError(f"{where}: {exc}") from None
    return UrdfChain(chain, tuple(names), np.array(lower), np.array(upper), np.array(velocity), where)


def chain_from_urdf(path_or_text, base_link: str = "base_link", flange_link: str = "tool0",
                    joint_names=None) -> SerialChain:
    """The :class:`~spherecal.core.kinematics.SerialChain` (mm) from ``base_link`` to
    ``flange_link`` of a URDF; see :func:`read_urdf_chain`."""
    return read_urdf_chain(path_or_text, base_link, flange_link, joint_names).chain


# ---------------------------------------------------------------------------------------
# inverse kinematics of a chain
# ---------------------------------------------------------------------------------------
def chain_jacobian(chain: SerialChain, q_rad) -> tuple[np.ndarray, np.ndarray]:
    """``base_from_flange`` (4x4, mm) and the geometric Jacobian (6 x n) at ``q_rad``:
    rows 0-2 the flange origin's velocity (mm/rad), rows 3-5 the angular velocity, both
    in the base frame."""
    q = np.asarray(q_rad, dtype=float).reshape(chain.n_joints)
    n = chain.n_joints
    R = np.eye(3)
    p = np.zeros(3)
    origins = np.empty((n, 3))
    axes = np.empty((n, 3))
    for i in range(n):
        P = chain.placements[i]
        p = p + R @ P[:3, 3]
        R = R @ P[:3, :3]
        origins[i] = p
        axes[i] = R @ chain.axes[i]
        R = R @ _axis_angle(chain.axes[i], q[i])
    F = chain.flange_placement
    T = np.eye(4)
    T[:3, 3] = p + R @ F[:3, 3]
    T[:3, :3] = R @ F[:3, :3]
    d = T[:3, 3] - origins  # (n, 3) from each joint to the flange
    J = np.empty((6, n))
    J[0] = axes[:, 1] * d[:, 2] - axes[:, 2] * d[:, 1]
    J[1] = axes[:, 2] * d[:, 0] - axes[:, 0] * d[:, 2]
    J[2] = axes[:, 0] * d[:, 1] - axes[:, 1] * d[:, 0]
    J[3:] = axes.T
    return T, J


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (rad); accurate for small and large angles."""
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    s = np.linalg.norm(w)
    c = (np.trace(R) - 1.0) / 2.0
    angle = math.atan2(s, c)
    if s < 1e-12:
        if c > 0:
            return w  # tiny angle: sin(angle) ~ angle
        # angle near pi: the axis from the symmetric part
        B = (R + np.eye(3)) / 2.0
        k = int(np.argmax(np.diag(B)))
        axis = B[:, k] / math.sqrt(max(B[k, k], 1e-300))
        return axis / np.linalg.norm(axis) * angle
    return w / s * angle


class IkNotConverged(InputError):
    """Numerical inverse kinematics did not reach the pose to its tolerance from its seed
    (the pose may still be reachable from another seed)."""


def chain_inverse_kinematics(
    chain: SerialChain,
    base_from_flange,
    seed_rad,
    *,
    tol_mm: float = 1e-9,
    tol_rad: float = 1e-9,
    max_iterations: int = 50,
) -> np.ndarray:
    """Joint angles (rad) that put the chain's flange at ``base_from_flange`` (4x4 mm),
    found by Newton steps from ``seed_rad`` (damped least squares near singularities).
    Converges to the solution nearest the seed when the seed is close (a nominal model's
    analytic solution is). Raises :class:`IkNotConverged` when position and rotation do
    not reach ``tol_mm`` and ``tol_rad``."""
    target = np.asarray(base_from_flange, dtype=float)
    q = np.array(seed_rad, dtype=float).reshape(chain.n_joints)
    err_p = err_r = math.inf
    for _ in range(max_iterations):
        T, J = chain_jacobian(chain, q)
        e = np.concatenate([target[:3, 3] - T[:3, 3], _rotvec(target[:3, :3] @ T[:3, :3].T)])
        err_p, err_r = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
        if err_p <= tol_mm and err_r <= tol_rad:
            return q
        # balance units: rotation rows in mm at a 1 m lever
        scale = np.array([1.0, 1.0, 1.0, 1000.0, 1000.0, 1000.0])
        U, s, Vt = np.linalg.svd(J * scale[:, None], full_matrices=False)
        lam = 1e-9 * s[0]
        step = Vt.T @ ((s / (s * s + lam * lam)) * (U.T @ (e * scale)))
        if not np.all(np.isfinite(step)):
            break
        q = q + step
    seed_deg = np.round(np.degrees(np.asarray(seed_rad, dtype=float).reshape(-1)), 1).tolist()
    raise IkNotConverged(
        f"inverse kinematics did not converge from the seed {seed_deg} deg (model convention): {err_p:.3g} mm and "
        f"{err_r:.3g} rad left after {max_iterations} iterations (tolerance {tol_mm:g} mm, {tol_rad:g} rad); the "
        "pose may be out of reach, or reachable from another seed (a seed at a singularity, such as a stretched "
        "elbow, converges badly)"
    )
