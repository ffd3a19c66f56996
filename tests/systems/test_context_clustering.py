"""ContextClustering LeafSystem: ports, FixValue, and a short simulation over two terrains."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from pcvfe_drake.contexts.clustering import ClusteringParams, ClusterTable
from pcvfe_drake.contexts.feature_streams import synthetic_feature_stream
from pcvfe_drake.systems.context_clustering import ContextClustering


def test_ports_and_defaults():
    system = ContextClustering(feature_dim=36)
    assert system.get_input_port(0).get_name() == "features"
    assert system.get_input_port(0).size() == 36
    assert system.GetOutputPort("context_id").size() == 1
    assert system.frame_period_s == pytest.approx(0.1)
    assert system.recluster_period_s == pytest.approx(10.0)
    # Output from state: no direct feedthrough, no algebraic loop with a downstream fitter.
    assert not system.HasDirectFeedthrough(0, system.GetOutputPort("context_id").get_index())
    context = system.CreateDefaultContext()
    assert system.GetOutputPort("context_id").Eval(context)[0] == -1
    table = system.GetOutputPort("cluster_table").Eval(context)
    assert isinstance(table, ClusterTable) and table.records == []
    with pytest.raises(ValueError, match="feature_dim"):
        ContextClustering(feature_dim=0)
    with pytest.raises(ValueError, match="recluster_period_s"):
        ContextClustering(recluster_period_s=-1.0)


def test_fixed_input_forms_one_context_after_the_first_reclustering():
    system = ContextClustering(feature_dim=4)
    context = system.CreateDefaultContext()
    z = np.array([0.1, 0.7, 0.2, 0.05])
    system.get_input_port(0).FixValue(context, z)
    simulator = Simulator(system, context)
    simulator.AdvanceTo(9.95)
    assert system.GetOutputPort("context_id").Eval(context)[0] == -1  # nothing clustered yet
    simulator.AdvanceTo(10.25)
    assert system.GetOutputPort("context_id").Eval(context)[0] == 0
    table = system.GetOutputPort("cluster_table").Eval(context)
    assert table.active_ids == [0]
    assert table.recluster_time_s == pytest.approx(10.0)
    rec = table.record(0)
    np.testing.assert_allclose(rec.centroid, z)
    assert rec.first_seen_s == pytest.approx(0.0)
    assert rec.last_seen_s == pytest.approx(10.2)
    assert rec.size == pytest.approx(103)  # frames at 0.0, 0.1, ..., 10.2
    stored = system.GetOutputPort("stored_features").Eval(context)
    assert stored.n_reclusterings == 1 and stored.z.shape[1] == 4
    # frame_labels: the same frames' times (ordered) and labels, the version, the frame period.
    frames = system.GetOutputPort("frame_labels").Eval(context)
    np.testing.assert_array_equal(frames.t_s, np.sort(stored.t_s))
    assert frames.version == 1 and frames.frame_period_s == pytest.approx(0.1)
    assert np.all(frames.labels == 0) and frames.labels.size == stored.labels.size
    assert 0 < len(stored.z) <= 103 and np.all(stored.labels == 0)
    np.testing.assert_allclose(stored.z, np.tile(z, (len(stored.z), 1)))
    assert np.all(np.diff(np.sort(stored.t_s)) > 0) and stored.t_s.max() <= 10.2 + 1e-9
    # A corrupt frame (NaN) is reported as noise, not stored, and does not stop the simulation.
    system.get_input_port(0).FixValue(context, np.full(4, np.nan))
    simulator.AdvanceTo(10.35)
    assert system.GetOutputPort("context_id").Eval(context)[0] == -1
    assert system.clusterer(context).n_frames == 103


def _two_terrain_ids(params: ClusteringParams):
    """The published context ids of terrain A 0-25 s, B 25-45 s, A again from ~45 s (10 Hz
    frames, 36 numbers each) over 52 s: (t, ids, the true terrain label of each id's frame,
    the clustering system and its context at the end)."""
    stream = synthetic_feature_stream(
        n_laps=2, terrain_durations_s=(25.0, 20.0), outlier_fraction=0.0, seed=5
    )
    builder = DiagramBuilder()
    source = builder.AddNamedSystem(
        "features",
        TrajectorySource(PiecewisePolynomial.ZeroOrderHold(stream.t_s, stream.z.T)),
    )
    clustering = builder.AddNamedSystem("context_clustering", ContextClustering(36, params))
    builder.Connect(source.get_output_port(), clustering.GetInputPort("features"))
    logger = LogVectorOutput(clustering.GetOutputPort("context_id"), builder, 0.1)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(52.0)

    log = logger.FindLog(simulator.get_context())
    t, ids = log.sample_times(), log.data()[0]
    # Frame k's id is published from t = 0.1 k + 0.1 on (zero-order hold).
    truth = stream.label[np.clip(np.round(t * 10).astype(int) - 1, 0, None)]
    return t, ids, truth, clustering, clustering.GetMyContextFromRoot(simulator.get_context())


def test_simulation_two_terrains_new_id_and_reidentification():
    t, ids, truth, clustering, context = _two_terrain_ids(ClusteringParams(frame_rate_hz=10.0))
    a_start = 0
    b = (truth == 1) & (t < 45.0)
    a_again = (truth == 0) & (t > 45.0)
    assert np.all(ids[t < 10.05] == -1)
    a_id = ids[(t > 10.5) & (truth == 0)]
    assert np.all(a_id == a_start)
    # B: noise (never A's id) until a re-clustering holds enough of it, then a new id.
    assert not np.any(ids[b] == a_start)
    b_after = ids[b & (t > 40.5)]
    assert b_after.size > 30 and np.mean(b_after == 1) > 0.95
    # Back on A: re-identified within a few frames.
    first_a_again = t[a_again][0]
    hits = t[a_again & (ids == a_start)]
    assert hits[0] - first_a_again <= 0.3
    table = clustering.GetOutputPort("cluster_table").Eval(context)
    assert table.active_ids == [0, 1]
    assert table.n_reclusterings == 5


class _FrameStamp:
    """A camera stand-in: a LeafSystem whose output (from state) is the time of its latest
    frame, updated every 0.1 s at offset 0 like the TextureCamera."""

    @staticmethod
    def make():
        from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

        class FrameStamp(LeafSystem):
            def __init__(self) -> None:
                super().__init__()
                index = self.DeclareDiscreteState(BasicVector([-1.0]))
                self.DeclarePeriodicDiscreteUpdateEvent(0.1, 0.0, self._frame)
                self.DeclareStateOutputPort("features", index)

            def _frame(self, context, discrete_state):
                discrete_state.set_value([context.get_time()])
                return EventStatus.Succeeded()

        return FrameStamp()


@pytest.mark.parametrize(("offset_s", "age_s"), [(0.001, 0.001), (0.0, 0.1)])
def test_frame_offset_assigns_the_frame_of_the_same_period(offset_s, age_s):
    from pcvfe_drake.contexts.clustering import ContextClusterer

    class Recording(ContextClusterer):
        def __init__(self, params):
            super().__init__(params)
            self.seen: list[tuple[float, float]] = []
            self.speeds: list[float | None] = []

        def assign(self, z, t_s, speed_mps=None):
            self.seen.append((float(t_s), float(z[0])))
            self.speeds.append(speed_mps)
            return super().assign(z, t_s, speed_mps)

    builder = DiagramBuilder()
    camera = builder.AddSystem(_FrameStamp.make())
    clustering = builder.AddSystem(ContextClustering(feature_dim=1, frame_offset_s=offset_s))
    builder.Connect(camera.get_output_port(0), clustering.get_input_port(0))
    diagram = builder.Build()
    root = diagram.CreateDefaultContext()
    params = clustering.params
    mine = clustering.GetMyMutableContextFromRoot(root)
    mine.get_mutable_abstract_state(0).set_value(Recording(params))
    # the measured state's speed (index 3) reaches every frame's assignment
    clustering.GetInputPort("state").FixValue(mine, [0.0, 0.0, 0.0, 7.5, 0.0, 0.0, 0.0])
    simulator = Simulator(diagram, root)
    simulator.AdvanceTo(1.05)
    assert clustering.clusterer(clustering.GetMyContextFromRoot(root)).speeds == [7.5] * 11
    seen = np.array(clustering.clusterer(clustering.GetMyContextFromRoot(root)).seen)
    assert len(seen) == 11
    np.testing.assert_allclose(seen[:, 0], np.arange(11) * 0.1 + offset_s, atol=1e-9)
    # Age of the frame at its assignment: 1 ms with the offset, a whole period without it.
    np.testing.assert_allclose((seen[:, 0] - seen[:, 1])[1:], age_s, atol=1e-9)
    assert clustering.frame_offset_s == offset_s
    with pytest.raises(ValueError, match="frame_offset_s"):
        ContextClustering(feature_dim=1, frame_offset_s=0.1)


def test_novelty_trigger_names_a_new_terrain_without_waiting_for_the_period():
    # The same terrains as above, with the novelty trigger.
    params = ClusteringParams(frame_rate_hz=10.0, novelty_window_s=5.0)
    t, ids, truth, clustering, context = _two_terrain_ids(params)
    # A is named once 5 s of it are stored (the periodic re-clustering would wait until 10 s).
    first_a = t[(ids == 0) & (truth == 0)][0]
    assert 4.0 <= first_a <= 7.0
    # B too: a few seconds after its entry (25.6 s, after the transition strip), not at the
    # re-clustering of 40 s.
    b = (truth == 1) & (t < 45.0)
    assert not np.any(ids[b] == 0)
    first_b = t[b & (ids == 1)][0]
    assert first_b - t[b][0] <= 7.0
    assert np.mean(ids[b & (t > first_b + 1.0)] == 1) > 0.95
    # Back on A: re-identified with its old id (Algorithm 1 across triggered re-clusterings).
    a_again = (truth == 0) & (t > 45.0)
    assert t[a_again & (ids == 0)][0] - t[a_again][0] <= 0.3
    table = clustering.GetOutputPort("cluster_table").Eval(context)
    assert table.active_ids == [0, 1]
    # Periodic ones (5 by 52 s) plus the triggered ones, at most one per min interval while noise
    # piles up: a handful, not one per frame.
    assert 5 < table.n_reclusterings <= 5 + 12
    frames = clustering.GetOutputPort("frame_labels").Eval(context)
    assert frames.version == table.n_reclusterings
