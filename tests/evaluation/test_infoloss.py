from __future__ import annotations

import numpy as np
import pytest

from lessmap.errors import DatasetError
from lessmap.evaluation.scores.infoloss import (
    LandmarkInformation,
    block_mass,
    information_loss,
    information_matrix,
    landmark_information,
    landmark_submaps,
    marginalize,
)
from tests.evaluation.helpers import small_problem

# -- the information matrix ------------------------------------------------------------------


def measure(pose: np.ndarray, mark: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rotation_t = np.array([[c, s], [-s, c]])
    result: np.ndarray = rotation_t @ (mark - pose[:2])
    return result


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.concatenate([measure(a, b[:2]), [b[2] - a[2]]])


def numeric_jacobian(f, x: np.ndarray, step: float = 1e-6) -> np.ndarray:  # type: ignore[no-untyped-def]
    cols = []
    for k in range(x.size):
        dx = np.zeros_like(x)
        dx[k] = step
        cols.append((f(x + dx) - f(x - dx)) / (2 * step))
    return np.column_stack(cols)


def test_information_matrix_is_jt_omega_j_with_numeric_jacobians() -> None:
    rng = np.random.default_rng(7)
    poses = [(0.0, 0.0, 0.3), (1.0, 0.5, 1.1), (2.0, 0.2, -0.7)]
    marks = [(0.5, 2.0), (2.5, -1.0), (1.0, 1.0)]
    sightings = [(0, 0), (0, 2), (1, 0), (1, 1), (2, 1), (2, 2)]
    problem = small_problem(poses, marks, sightings, rng=rng)
    m, n = 3, 3
    size = 3 * m + 2 * n
    expected = np.zeros((size, size))
    rows, cols = np.triu_indices(2)
    for k, (p, lm) in enumerate(sightings):
        omega = np.zeros((2, 2))
        omega[rows, cols] = problem.obs_information[k]
        omega[cols, rows] = problem.obs_information[k]
        state = np.concatenate([problem.poses[p], problem.landmarks[lm]])
        jac = numeric_jacobian(lambda v: measure(v[:3], v[3:]), state)
        index = [3 * p, 3 * p + 1, 3 * p + 2, 3 * m + 2 * lm, 3 * m + 2 * lm + 1]
        expected[np.ix_(index, index)] += jac.T @ omega @ jac
    rows, cols = np.triu_indices(3)
    for k in range(m - 1):
        omega = np.zeros((3, 3))
        omega[rows, cols] = problem.odo_information[k]
        omega[cols, rows] = problem.odo_information[k]
        state = np.concatenate([problem.poses[k], problem.poses[k + 1]])
        jac = numeric_jacobian(lambda v: relative(v[:3], v[3:]), state)
        index = list(range(3 * k, 3 * k + 6))
        expected[np.ix_(index, index)] += jac.T @ omega @ jac
    expected[:3, :3] += 5.0 * np.eye(3)
    got = information_matrix(problem, anchor_information=5.0).toarray()
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(got, got.T)


def test_anchor_must_be_positive() -> None:
    problem = small_problem([(0.0, 0.0, 0.0)], [(1.0, 0.0)], [(0, 0)])
    with pytest.raises(ValueError, match="anchor_information"):
        information_matrix(problem, anchor_information=0.0)


# -- a problem small enough to write out by hand ------------------------------------------------


def hand_problem_h(anchor: float) -> np.ndarray:
    """H of p0 = (0,0,0), p1 = (1,0,0), a = (0,1) seen from both, b = (1,1) from p1; unit Ω.

    State [p0 (3), p1 (3), a (2), b (2)]. At θ = 0 a sighting of l from t has
    J_pose = [[-1, 0, dy], [0, -1, -dx]], J_landmark = I with (dx, dy) = l - t; odometry
    p0 -> p1 has J_p0 = [[-1, 0, 0], [0, -1, -1], [0, 0, -1]] (dx = 1), J_p1 = I.
    """
    h = np.zeros((10, 10))

    def add(blocks: dict[int, np.ndarray]) -> None:
        rows = sum(b.shape[0] for b in blocks.values()) // len(blocks)
        jac = np.zeros((rows, 10))
        for start, block in blocks.items():
            jac[:, start : start + block.shape[1]] = block
        h[:] += jac.T @ jac

    eye2 = np.eye(2)
    add({0: np.array([[-1.0, 0, 1], [0, -1, 0]]), 6: eye2})  # p0 sees a: d = (0, 1)
    add({3: np.array([[-1.0, 0, 1], [0, -1, 1]]), 6: eye2})  # p1 sees a: d = (-1, 1)
    add({3: np.array([[-1.0, 0, 1], [0, -1, 0]]), 8: eye2})  # p1 sees b: d = (0, 1)
    add({0: np.array([[-1.0, 0, 0], [0, -1, -1], [0, 0, -1]]), 3: np.eye(3)})
    h[:3, :3] += anchor * np.eye(3)
    return h


def test_hand_computed_problem() -> None:
    problem = small_problem(
        [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0)], [(0.0, 1.0), (1.0, 1.0)], [(0, 0), (1, 0), (1, 1)]
    )
    anchor = 1e6
    h = hand_problem_h(anchor)
    np.testing.assert_allclose(information_matrix(problem, anchor).toarray(), h, atol=1e-12)

    marginal = h[6:, 6:] - h[6:, :6] @ np.linalg.inv(h[:6, :6]) @ h[:6, 6:]
    mass = np.abs(marginal)
    e_split = (mass[:2, 2:].sum() + mass[2:, :2].sum()) / mass.sum()
    info = landmark_information(problem, anchor)
    np.testing.assert_allclose(info.matrix, marginal, rtol=1e-6, atol=1e-9)
    assert information_loss(info, {100: {0}, 101: {1}}) == pytest.approx(e_split, rel=1e-6)
    assert 0.0 < e_split < 1.0
    assert information_loss(info, {100: {0}, 101: {0}}) == 0.0
    assert information_loss(info, {100: {0, 1}, 101: {1}}) == 0.0  # a shares submap 1 with b

    # The prior is the limit of a fixed first pose: drop p0's rows altogether.
    fixed = h[3:, 3:]
    exact = fixed[3:, 3:] - fixed[3:, :3] @ np.linalg.inv(fixed[:3, :3]) @ fixed[:3, 3:]
    np.testing.assert_allclose(info.matrix, exact, rtol=1e-4, atol=1e-6)


# -- Schur complement -------------------------------------------------------------------------


def test_sparse_schur_matches_dense_inverse() -> None:
    rng = np.random.default_rng(11)
    m, n = 12, 150  # 300 landmark columns: more than one block of solved columns
    poses = [(float(k), float(rng.normal()), float(rng.uniform(-3, 3))) for k in range(m)]
    marks = [tuple(rng.uniform(-2, 14, size=2)) for _ in range(n)]
    sightings = sorted(
        {(k % m, k) for k in range(n)}
        | {(int(rng.integers(m)), int(rng.integers(n))) for _ in range(200)}
    )
    problem = small_problem(poses, marks, sightings, rng=rng)
    h = information_matrix(problem, anchor_information=1e3)
    dense = h.toarray()
    p = 3 * m
    reference = dense[p:, p:] - dense[p:, :p] @ np.linalg.inv(dense[:p, :p]) @ dense[:p, p:]
    got = marginalize(h, p)
    np.testing.assert_allclose(got, reference, rtol=1e-8, atol=1e-8 * np.abs(reference).max())
    np.testing.assert_array_equal(got, got.T)


def test_marginalize_reports_a_singular_pose_block() -> None:
    h = np.zeros((5, 5))
    h[3:, 3:] = np.eye(2)
    from scipy import sparse

    with pytest.raises(DatasetError, match="singular"):
        marginalize(sparse.csc_array(h), 3)


def test_block_mass_sums_absolute_blocks() -> None:
    matrix = np.arange(16, dtype=float).reshape(4, 4) - 8.0
    mass = block_mass(matrix)
    assert mass.shape == (2, 2)
    assert mass[0, 1] == np.abs(matrix[:2, 2:]).sum()
    assert mass.sum() == np.abs(matrix).sum()


# -- e (Eq. 5) ------------------------------------------------------------------------------


def chain_problem() -> LandmarkInformation:
    """Landmarks 100, 101 seen together from every pose; 102 only from the last one."""
    poses = [(float(k), 0.0, 0.1 * k) for k in range(6)]
    marks = [(2.0, 1.0), (2.5, -1.0), (7.0, 1.5)]
    sightings = [(k, 0) for k in range(6)] + [(k, 1) for k in range(6)] + [(5, 2)]
    return landmark_information(small_problem(poses, marks, sightings))


def test_e_is_zero_for_a_single_submap() -> None:
    info = chain_problem()
    assert information_loss(info, {100: {0}, 101: {0}, 102: {0}}) == 0.0


def test_e_grows_when_a_strongly_linked_pair_is_split() -> None:
    info = chain_problem()
    weak = information_loss(info, {100: {0}, 101: {0}, 102: {1}})
    strong = information_loss(info, {100: {0}, 101: {1}, 102: {1}})
    everything = information_loss(info, {100: {0}, 101: {1}, 102: {2}})
    assert 0.0 < weak < strong < everything < 1.0


def test_e_needs_every_landmark_in_a_submap() -> None:
    info = chain_problem()
    with pytest.raises(DatasetError, match="in no submap"):
        information_loss(info, {100: {0}, 101: {0}})


def test_landmark_submaps_rules() -> None:
    frames = [[1, 2], [2, 3], [3], [3, 4], [4]]
    labels = [0, 0, 1, 1, 1]
    assert landmark_submaps(frames, labels) == {1: {0}, 2: {0}, 3: {0, 1}, 4: {1}}
    exclusive = landmark_submaps(frames, labels, exclusive=True)
    assert exclusive == {1: {0}, 2: {0}, 3: {1}, 4: {1}}  # 3: once in 0, twice in 1
    tie = landmark_submaps([[7], [7]], [0, 1], exclusive=True)
    assert tie == {7: {0}}  # ties go to the earliest submap
    with pytest.raises(ValueError, match="labels"):
        landmark_submaps(frames, labels[:-1])
