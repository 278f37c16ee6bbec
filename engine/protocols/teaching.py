"""Teaching experiments: small set-ups whose outcome a formula from the papers predicts.

- :func:`collision`: two disks head-on; restitution and contact duration of the linear
  spring-dashpot, ``e_N = exp(-pi zeta / sqrt(1 - zeta²))`` (Gilabert Sec. II C).
- :func:`closed_path`: ratcheting Fig. 8; the upper disk is carried around a closed path
  without rotating or sliding; the tangential spring changes by ``a / (r_i + r_j)`` for the
  Cundall-Strack spring (ratcheting Eq. 17) and not at all for the angle-based spring.
- :func:`block`: quasi-rigidity Sec. II C, Figs. 2-3; a non-rotating disk pressed on a wall,
  the tangential load ramped past ``mu F_n`` and back: the principle of minimum sliding.

Each returns a result dataclass with ``as_dict()`` for JSON output.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..params import TANGENTIAL, ContactLaw, Integration, Wall, friction_coefficient, nonnegative, positive
from ..simulation import Simulation
from ..state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS, ParticleState


class _Result:
    def as_dict(self) -> dict:
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                value = value.tolist()
            out[f.name] = value
        return out


def _pair_law(model: str, zeta: float, mu: float, stiffness: float, tangential_damping: float = 0.0) -> ContactLaw:
    return ContactLaw(normal_stiffness=stiffness, tangential_stiffness=stiffness, friction=mu, damping_ratio=zeta,
                      tangential_damping=tangential_damping, tangential_model=model)


# ---------------------------------------------------------------------------------------------- collision
def restitution(zeta):
    """The linear spring-dashpot's normal restitution, ``exp(-pi zeta / sqrt(1 - zeta²))`` (Gilabert
    Eq. 6), of a damping ratio or an array of them."""
    return np.exp(-np.pi * zeta / np.sqrt(1.0 - np.square(zeta)))


def contact_duration(zeta: float, stiffness: float, reduced_mass: float) -> float:
    """How long the overlap lasts: half a period of the damped oscillator, ``pi / (w0 sqrt(1 - zeta²))``."""
    return math.pi / (math.sqrt(stiffness / reduced_mass) * math.sqrt(1.0 - zeta * zeta))


@dataclass(frozen=True)
class CollisionResult(_Result):
    restitution: float
    restitution_predicted: float
    contact_duration: float
    contact_duration_predicted: float
    steps_in_contact: int
    dt: float
    zeta: float
    model: str


def collision(model: str = "cundall-strack", zeta: float = 0.3, mu: float = 0.5, dt: float | None = None,
              stiffness: float = 1.0e4, radius: float = 0.5, mass: float = 1.0, speed: float = 1.0,
              steps_per_collision: int = 200) -> CollisionResult:
    """Two equal disks approach head-on at relative speed ``2 speed``.

    Predictions for the linear spring-dashpot with ``m_eff = m/2``, ``w0 = sqrt(K_n/m_eff)``:
    ``e_N = exp(-pi zeta / sqrt(1 - zeta²))`` and duration ``pi / (w0 sqrt(1 - zeta²))``
    (the contact ends when the overlap closes). ``dt`` defaults to 1/``steps_per_collision``
    of the predicted duration.
    """
    zeta = nonnegative("zeta", zeta)
    law = _pair_law(model, zeta, mu, positive("stiffness", stiffness))
    positive("radius", radius)
    positive("mass", mass)
    positive("speed", speed)
    duration_predicted = contact_duration(zeta, stiffness, 0.5 * mass)
    if dt is None:
        dt = duration_predicted / steps_per_collision
    gap = 0.05 * radius
    particles = ParticleState([[-radius - gap, 0.0], [radius + gap, 0.0]], [radius, radius],
                              velocity=[[speed, 0.0], [-speed, 0.0]], mass=[mass, mass])
    sim = Simulation(particles, law, Integration(dt=dt))
    approach = 2.0 * speed
    touching = 0
    max_steps = int(10 * (duration_predicted + 2 * gap / approach) / sim.dt) + 10
    for _ in range(max_steps):
        sim.run(1)
        if sim.contacts.surface_gap[:sim.contacts.count].min(initial=np.inf) < 0:
            touching += 1
        elif touching:
            break
    else:
        raise RuntimeError("the disks did not separate: the collision did not end")
    sim.run(1)  # the step that found them apart applied the dashpot's last share: its second half kick
    relative = sim.particles.velocity[1, 0] - sim.particles.velocity[0, 0]
    return CollisionResult(
        restitution=float(relative / approach),
        restitution_predicted=float(restitution(zeta)),
        contact_duration=touching * sim.dt, contact_duration_predicted=duration_predicted,
        steps_in_contact=touching, dt=sim.dt, zeta=zeta, model=model)


# ---------------------------------------------------------------------------------------------- closed path
@dataclass(frozen=True)
class ClosedPathResult(_Result):
    model: str
    delta_Dt: float
    predicted_delta_Dt: float
    enclosed_area: float
    final_position_error: float
    max_abs_Dt: float
    slid: bool
    path: np.ndarray


def closed_path(model: str = "cundall-strack", mu: float = math.inf, dt: float | None = None, zeta: float = 0.0,
                radius: float = 0.5, stiffness: float = 1.0e5, overlap: float = 2.0e-3, depth: float = 2.0e-3,
                turn: float = 0.02, steps_per_side: int = 400) -> ClosedPathResult:
    """Ratcheting Fig. 8: carry the upper disk around A -> B -> C -> D -> A.

    The lower disk (j) is fixed at the origin; the upper disk (i) starts at A above it with
    overlap ``overlap``, moves ``depth`` towards j (B), turns by ``turn`` radians about j at
    that distance (C), moves back out (D) and turns back (A). Neither disk rotates; with
    ``mu = inf`` nothing slides. Returns the change of the tangential spring D_t, the
    enclosed area ``a`` (signed, counter-clockwise positive) and Eq. 17's prediction:
    ``a / (r_i + r_j)`` for the Cundall-Strack spring, 0 for the alpha-corrected and
    angle-based springs (whose D_t depends only on positions).
    """
    law = _pair_law(model, nonnegative("zeta", zeta), mu, positive("stiffness", stiffness))
    for name, value in (("radius", radius), ("overlap", overlap), ("depth", depth), ("turn", turn)):
        positive(name, value)
    if overlap + depth >= radius:
        raise ParameterError("overlap + depth", overlap + depth, f"less than the radius {radius}")
    d_a = 2.0 * radius - overlap
    d_b = d_a - depth
    phi0 = 0.5 * math.pi
    corners = [(d_a, phi0), (d_b, phi0), (d_b, phi0 + turn), (d_a, phi0 + turn), (d_a, phi0)]
    particles = ParticleState([[0.0, d_a], [0.0, 0.0]], [radius, radius], mass=[1.0, 1.0],
                              kind=["kinematic", "fixed"])
    sim = Simulation(particles, law, Integration(dt=dt, initial_overlap=0.05))
    path = []
    slid = False
    max_dt = 0.0

    def spring() -> float:
        rows = sim.contacts.count
        return float(sim.contacts.tangential_spring[:rows][0]) if rows else 0.0

    start = spring()
    for (r0, a0), (r1, a1) in zip(corners[:-1], corners[1:]):
        for k in range(1, steps_per_side + 1):
            s = k / steps_per_side
            r = r0 + (r1 - r0) * s
            a = a0 + (a1 - a0) * s
            target = np.array([r * math.cos(a), r * math.sin(a)])
            velocity = (target - sim.particles.position[0]) / sim.dt
            sim.set_motion(0, velocity, 0.0)
            sim.run(1)
            status = sim.contacts.status[0]
            slid = slid or status in (STATUS_SLIDE_POS, STATUS_SLIDE_NEG)
            max_dt = max(max_dt, abs(spring()))
            path.append((sim.contacts.normal_force[0], sim.contacts.tangential_force[0]))
    final_error = float(np.hypot(*(sim.particles.position[0] - [0.0, d_a])))
    # signed area of the closed path (shoelace on the polar path), counter-clockwise positive
    area = 0.5 * turn * (d_b ** 2 - d_a ** 2)
    predicted = area / (2.0 * radius) if TANGENTIAL[model].path_dependent else 0.0
    return ClosedPathResult(model=model, delta_Dt=spring() - start, predicted_delta_Dt=predicted,
                            enclosed_area=abs(area), final_position_error=final_error, max_abs_Dt=max_dt,
                            slid=bool(slid), path=np.array(path))


# ---------------------------------------------------------------------------------------------- block
@dataclass(frozen=True)
class BlockResult(_Result):
    mu: float
    normal_load: float
    max_Ft_over_muFn: float
    friction_work_positive: bool
    friction_work_per_slide: list
    slid: bool
    slide_start_load_ratio: float
    slide_end_load_ratio: float
    stuck_again: bool
    sliding_while_load_below_limit_and_at_rest: int
    slip_distance: float
    path: np.ndarray
    load: np.ndarray
    sliding: np.ndarray


def block(mu: float = 0.5, zeta: float = 0.7, dt: float | None = None, model: str = "cundall-strack",
          normal_load: float = 1.0, peak_ratio: float = 1.5, ramp_time: float = 10.0, stiffness: float = 1.0e3,
          radius: float = 0.5, mass: float = 1.0, samples: int = 400) -> BlockResult:
    """Quasi-rigidity Figs. 2-3: a block (a disk that cannot turn) on a wall, loaded tangentially.

    The disk rests on the wall ``y = 0`` under a normal load ``normal_load``; a tangential load
    rises linearly from 0 to ``peak_ratio mu normal_load`` in ``ramp_time`` and falls back to 0
    in the same time. Reports the contact's (F_n, F_t) path, the largest ``|F_t| / (mu F_n)``,
    the load ratios at which sliding starts and stops, whether it ever slid while the load was
    below the limit and the block at rest, and the work friction did on the block during each
    episode of sliding (it must be negative: friction never does positive work).
    """
    mu = friction_coefficient("mu", mu, slides=True, holds=True, why="the block holds, then slides")
    positive("normal_load", normal_load)
    positive("peak_ratio", peak_ratio)
    positive("ramp_time", ramp_time)
    damping = 2.0 * zeta * math.sqrt(stiffness * mass)
    law = _pair_law(model, nonnegative("zeta", zeta), mu, positive("stiffness", stiffness), damping)
    rest = normal_load / stiffness
    particles = ParticleState([[0.0, radius - rest]], [radius], mass=[mass], inertia=[math.inf])
    particles.external_force[0] = (0.0, -normal_load)
    floor = Wall((0.0, 1.0), 0.0, name="floor")
    integration = Integration(dt=dt, dt_safety=0.3)
    sim = Simulation(particles, law, integration, walls=(floor,))
    sim.run_for(10.0 * math.sqrt(mass / stiffness) * 2 * math.pi)
    limit = mu * normal_load
    total_steps = int(round(2.0 * ramp_time / sim.dt))
    per_sample = max(1, total_steps // samples)
    path, loads, sliding = [], [], []
    episodes = []
    max_ratio = 0.0
    slid = False
    start_ratio = end_ratio = math.nan
    bad_sliding = 0
    was_sliding = False
    x_start = float(sim.particles.position[0, 0])
    for step in range(total_steps + int(round(ramp_time / 4 / sim.dt))):
        t = (step + 1) * sim.dt
        load = peak_ratio * limit * (t / ramp_time if t <= ramp_time else max(0.0, 2.0 - t / ramp_time))
        sim.particles.external_force[0, 0] = load
        sim.run(1)
        fn = float(sim.contacts.normal_force[0])
        ft = float(sim.contacts.tangential_force[0])
        status = int(sim.contacts.status[0])
        is_sliding = status in (STATUS_SLIDE_POS, STATUS_SLIDE_NEG)
        velocity = float(sim.particles.velocity[0, 0])
        if fn > 0:
            max_ratio = max(max_ratio, abs(ft) / (mu * fn))
        if is_sliding:
            if not was_sliding:
                episodes.append(0.0)
            # the friction force on the block is -F_t along x (t = z × n points to -x)
            episodes[-1] += -ft * velocity * sim.dt
            if load < limit * (1.0 - 1e-3) and abs(velocity) < 1e-9 * math.sqrt(stiffness / mass):
                bad_sliding += 1
        if is_sliding and not was_sliding and not slid:
            start_ratio = load / limit
        if was_sliding and not is_sliding:
            end_ratio = load / limit
        slid = slid or is_sliding
        was_sliding = is_sliding
        if step % per_sample == 0:
            path.append((fn, ft))
            loads.append(load)
            sliding.append(is_sliding)
    return BlockResult(
        mu=mu, normal_load=normal_load, max_Ft_over_muFn=max_ratio,
        friction_work_positive=any(work > 0 for work in episodes), friction_work_per_slide=episodes,
        slid=slid, slide_start_load_ratio=start_ratio, slide_end_load_ratio=end_ratio,
        stuck_again=not was_sliding, sliding_while_load_below_limit_and_at_rest=bad_sliding,
        slip_distance=float(sim.particles.position[0, 0] - x_start), path=np.array(path), load=np.array(loads),
        sliding=np.array(sliding))


EXPERIMENTS = {"collision": collision, "closed-path": closed_path, "block": block}
