"""Samples side by side in one simulation (engine/batch.py) and the ratchet study run as one batch: each sample
in a batch follows the same sample stepped alone, and a wall meets only its own sample's disks."""

import numpy as np
import pytest

from granlab.engine import ParticleState, Simulation
from granlab.engine.batch import Batch
from granlab.engine.errors import DivergenceError, ParameterError
from granlab.engine.params import PeriodicCell, Wall
from granlab.engine.protocols.cyclic import apply_load, wall_loads
from granlab.engine.protocols.prepare import compress
from granlab.engine import studies
from granlab.engine.studies import RatchetStudy, model_sim, ratchet_batch, ratchet_sample, run_ratchet_study

STUDY = RatchetStudy(particles=16, samples=3, cycles=6, batched=True)


@pytest.fixture(scope="module")
def boxes():
    """Three prepared boxes of 16 disks (seeds 0-2), ready to cycle with the Cundall-Strack spring."""
    return [model_sim(compress(16, seed=seed, pressure=1.0, friction=0.2).sim, STUDY, "cundall-strack")
            for seed in range(3)]


def alone(boxes, dt):
    copies = [box.clone() for box in boxes]
    for copy in copies:
        copy.set_dt(dt)
    return copies


def test_a_sample_in_a_batch_follows_it_stepped_alone(boxes):
    """300 steps at the prepared pressure, then 300 under the cyclic load: the unshifted sample bit for bit at
    first, every sample's disks and walls within 1e-12 of the box's length of the sample stepped alone."""
    batch = Batch([box.clone() for box in boxes])
    single = alone(boxes, batch.sim.dt)
    batch.sim.run(300)
    for copy in single:
        copy.run(300)
    first = batch.sample(0)
    assert np.array_equal(first.particles.position, single[0].particles.position)
    assert np.array_equal(first.walls.offset, single[0].walls.offset)
    for name, load in wall_loads(STUDY.load(), batch.sim.time).items():
        batch.set_wall_load(name, load)
    for copy in single:
        apply_load(copy, STUDY.load())
    batch.sim.run(300)
    for copy in single:
        copy.run(300)
    for k, copy in enumerate(single):
        back = batch.sample(k)
        assert back.step == copy.step and back.time == pytest.approx(copy.time, rel=1e-14)
        assert np.max(np.abs(back.particles.position - copy.particles.position)) < 1e-12
        assert np.max(np.abs(back.walls.offset - copy.walls.offset)) < 1e-12
        assert np.max(np.abs(back.particles.angle - copy.particles.angle)) < 1e-10
        assert batch.box_lengths()[k] == pytest.approx(copy.box_lengths(), abs=1e-12)


def test_a_sample_brought_back_at_once_is_the_sample_given(boxes):
    """Shifted into the batch and back: the disks within rounding of the shift, the contacts' rows, springs and
    wall anchors the same, the clock and the walls' loads the sample's."""
    given = [box.clone() for box in boxes]
    for box in given:
        apply_load(box, STUDY.load())
    expected = [box.export_state() for box in given]
    batch = Batch(given)
    assert batch.sim.particles.count == 48 and batch.sim.walls.count == 12
    for k in range(3):
        state = batch.sample(k).export_state()
        for key, value in expected[k].items():
            if key in ("dt", "step_origin", "time_origin", "workspace/flags", "workspace/info"):
                continue
            assert np.allclose(state[key], value, rtol=1e-14, atol=1e-14), key


def test_a_wall_meets_only_the_disks_it_is_given():
    """Two disks pressed 10 % into a floor that meets disk 0 alone: disk 0 is pushed up, disk 1 feels nothing."""
    floor = Wall(normal=(0.0, 1.0), position=0.0, name="floor", disks=(0, 1))
    sim = Simulation(ParticleState([[0.0, 0.9], [3.0, 0.9]], [1.0, 1.0]), walls=(floor,), check_initial_overlap=False)
    assert sim.particles.force[0, 1] > 0 and sim.particles.force[1, 1] == 0.0
    with pytest.raises(ParameterError, match="first < stop"):
        Wall(disks=(2, 1))
    with pytest.raises(ParameterError, match="stop at most 2"):
        Simulation(ParticleState([[0.0, 2.0], [3.0, 2.0]], [1.0, 1.0]), walls=(floor.replace(disks=(0, 3)),))


def test_a_batch_refuses_samples_it_cannot_put_side_by_side(boxes):
    cell = Simulation(ParticleState([[0.5, 0.5]], [0.2]), cell=PeriodicCell((2.0, 2.0)))
    with pytest.raises(ParameterError, match="periodic cell"):
        Batch([cell])
    other = boxes[1].clone(friction=0.5)
    with pytest.raises(ParameterError, match=r"samples\[1\] law"):
        Batch([boxes[0], other])
    with pytest.raises(ParameterError, match="at least one"):
        Batch([])


def test_a_batched_study_gives_each_sample_the_lengths_it_has_alone():
    """Six cycles of three samples: the box lengths at each cycle's start within 1e-7 of the samples cycled one
    by one (those step with their own time step, the batch with the smallest, 2 % apart), the same verdicts'
    sample count."""
    batched = ratchet_batch(STUDY, range(3))
    assert [result["seed"] for result in batched] == [0, 1, 2]
    for result in batched:
        single = ratchet_sample(STUDY, result["seed"], None)[0]
        assert result["error"] is None and len(result["length_x"]) == STUDY.cycles + 1
        assert np.allclose(result["length_x"], single["length_x"], rtol=1e-7, atol=0)
        assert np.allclose(result["length_y"], single["length_y"], rtol=1e-7, atol=0)


def test_a_batch_that_diverges_is_cycled_sample_by_sample(monkeypatch):
    def diverging(batch, study, model, progress):
        raise DivergenceError("an overlap above max_overlap", 10, 0.1)

    monkeypatch.setattr(studies, "_cycle_batch", diverging)
    results = ratchet_batch(STUDY.__class__(particles=16, samples=2, cycles=3, batched=True), range(2))
    assert [(r["seed"], r["error"]) for r in results] == [(0, None), (1, None)]


def test_a_batched_study_writes_no_run_files_and_says_why(tmp_path):
    with pytest.raises(ParameterError, match="not split by sample"):
        run_ratchet_study(STUDY, out_dir=str(tmp_path / "runs"))
    assert not (tmp_path / "runs").exists()
