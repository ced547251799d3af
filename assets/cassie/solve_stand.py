"""Solve the "stand" keyframe of cassie.xml so that both closed chains are exactly closed.

Fixed: hip roll = hip yaw = 0, knee, shin and heel springs at rest (0), pelvis level.
Solved (least squares, 15 equations / 15 unknowns):
  per leg: achilles ball rotation (3), tarsus, foot crank, plantar rod, foot (7 unknowns)
  shared : hip pitch (1)
equations:
  per leg: achilles and plantar connect residuals (6), toe height = heel height (1: foot flat)
  shared : whole-body COM x = mid-point of the four foot contact points in x (1)
  per leg: no spin of the achilles rod about its own axis (1; that direction is free)
Then the pelvis height is set so the foot spheres rest on the floor (sphere bottom at z = 0).

Run:  python assets/cassie/solve_stand.py   (prints the keyframe qpos line for cassie.xml)
"""

from __future__ import annotations

import pathlib

import mujoco
import numpy as np
from scipy.optimize import least_squares

HERE = pathlib.Path(__file__).resolve().parent
KNEE = -1.1997  # [rad] a standing knee angle (published standing pose)
SPHERE_R = 0.02  # [m] foot contact sphere radius


def _connect_residual(m, d):
    res = []
    for i in range(m.neq):
        b1, b2 = m.eq_obj1id[i], m.eq_obj2id[i]
        p1 = d.xpos[b1] + d.xmat[b1].reshape(3, 3) @ m.eq_data[i, 0:3]
        p2 = d.xpos[b2] + d.xmat[b2].reshape(3, 3) @ m.eq_data[i, 3:6]
        res.append(p1 - p2)
    return np.concatenate(res)


def solve(verbose: bool = True) -> np.ndarray:
    m = mujoco.MjModel.from_xml_path(str(HERE / "scene.xml"))
    d = mujoco.MjData(m)
    jq = lambda n: m.jnt_qposadr[m.joint(n).id]
    jv = lambda n: m.jnt_dofadr[m.joint(n).id]

    # starting guess: a standing posture close to the published one (the achilles ball joint
    # must start near its standing branch, about -24 deg about the rod frame's z axis)
    base = m.qpos0.copy()
    for side, quat in (("left", (0.9786, -0.0164, 0.0178, -0.2043)),
                       ("right", (0.9787, 0.0039, -0.0152, -0.2045))):
        a = jq(f"{side}_achilles")
        base[a:a + 4] = np.array(quat) / np.linalg.norm(quat)
        base[jq(f"{side}_knee")] = KNEE
        base[jq(f"{side}_tarsus")] = 1.4267
        base[jq(f"{side}_foot_crank")] = -1.524
        base[jq(f"{side}_plantar_rod")] = 1.506
        base[jq(f"{side}_foot")] = -1.597
    free_dofs = []
    for side in ("left", "right"):
        free_dofs += [jv(f"{side}_achilles") + k for k in range(3)]
        free_dofs += [jv(f"{side}_{n}") for n in ("tarsus", "foot_crank", "plantar_rod", "foot")]
    hip_pitch = [jq("left_hip_pitch"), jq("right_hip_pitch")]
    sites = [m.site(f"{s}_{e}").id for s in ("left", "right") for e in ("toe", "heel")]

    def qpos_of(x):
        q = base.copy()
        v = np.zeros(m.nv)
        v[free_dofs] = x[:-1]
        mujoco.mj_integratePos(m, q, v, 1.0)
        q[hip_pitch] = x[-1]
        return q

    def residual(x):
        d.qpos[:] = qpos_of(x)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        sp = d.site_xpos[sites]
        flat = [sp[0, 2] - sp[1, 2], sp[2, 2] - sp[3, 2]]
        com_x = d.subtree_com[1, 0] - sp[:, 0].mean()
        # the achilles rod may spin freely about its own axis (its x axis): pin that spin by
        # asking for zero x component of the ball joint's quaternion
        spin = [d.qpos[jq(f"{s}_achilles") + 1] for s in ("left", "right")]
        return np.concatenate([_connect_residual(m, d), flat, [com_x], spin])

    x0 = np.zeros(len(free_dofs) + 1)
    x0[-1] = 0.4973  # hip pitch [rad]
    sol = least_squares(residual, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    worst = np.abs(residual(sol.x)).max()
    q = qpos_of(sol.x)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    q[2] -= d.site_xpos[sites, 2].min() - SPHERE_R
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    if verbose:
        print("max |residual| =", worst)
        print("pelvis z =", q[2], " COM =", d.subtree_com[1])
        print("sites:\n", d.site_xpos[sites])
    return q


if __name__ == "__main__":
    q = solve()
    print(" ".join(f"{v:.9g}" for v in q))
