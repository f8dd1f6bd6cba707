"""training.evaluate.scenes.position: the free pieces of an iiwa14 position target's 4-D
fibre in a box scene (a coarse grid, two q7 layers, to keep it quick).

Against coal and the kinematic reference, both independent of the service's check: the
check's fast path changes no label (the pieces are those of coal alone); a node on a piece
is free by coal and a grid node on none is in collision; a piece never joins two of the
kinematic reference's components; the shares are the coal-free area's; and a free node's
own configuration lies on its piece.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from training.evaluate.references.iiwa14 import position_smm
from training.evaluate.scenes.boxes import SceneTarget, scene_target
from training.evaluate.scenes.coal_model import CoalModel
from training.evaluate.scenes.position import FreeRegions, free_regions_of_position
from training.evaluate.scenes.target import sphere_check

GRID, LAYERS = 12, 2
TARGET = 181  # of seed 7: its boxes cut the fibre into pieces


@pytest.fixture(scope="module")
def case() -> tuple[ServedModel, CoalModel, SceneTarget, FreeRegions, np.ndarray]:
    model = load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)
    coal = CoalModel.of(model)
    scene = scene_target(model, coal, 7, TARGET, 10, 0.0)
    regions, checked = free_regions_of_position(
        model, coal, sphere_check(model, scene.obstacles, 0.0).free,
        scene.q_target_rad, scene.obstacles, 0.0, GRID, LAYERS,
    )  # fmt: skip
    return model, coal, scene, regions, checked


def test_the_checks_fast_path_changes_no_piece(
    case: tuple[ServedModel, CoalModel, SceneTarget, FreeRegions, np.ndarray],
) -> None:
    model, coal, scene, regions, checked = case
    coal_only, _ = free_regions_of_position(
        model, coal, lambda q: np.zeros(len(q), dtype=bool),
        scene.q_target_rad, scene.obstacles, 0.0, GRID, LAYERS,
    )  # fmt: skip
    assert checked.any() and not checked.all()  # the check decided some, coal the rest
    np.testing.assert_array_equal(coal_only.label, regions.label)
    np.testing.assert_array_equal(coal_only.length_rad, regions.length_rad)


def test_pieces_are_coal_free_within_one_kinematic_component(
    case: tuple[ServedModel, CoalModel, SceneTarget, FreeRegions, np.ndarray],
) -> None:
    model, coal, scene, regions, _ = case
    kinematic = position_smm(model.kinematics(scene.q_target_rad[None]).position_m[0], 10, 0, GRID)
    grid_nodes = len(kinematic.node_q6_rad)
    on_piece = np.flatnonzero(regions.label >= 0)
    layer0 = np.flatnonzero(regions.layer == 0)[:grid_nodes]  # the grid nodes, in order
    np.testing.assert_allclose(regions.q_rad[layer0, :6], kinematic.node_q6_rad, atol=1e-6)
    rng = np.random.default_rng(0)
    sample = rng.choice(on_piece, 300, replace=False)
    assert coal.free(regions.q_rad[sample], scene.obstacles, 0.0).all()
    grid_row = np.concatenate(
        [np.flatnonzero(regions.layer == layer)[:grid_nodes] for layer in range(LAYERS)]
    )
    off = grid_row[regions.label[grid_row] < 0]
    assert len(off) > 0 and not coal.free(regions.q_rad[off[:300]], scene.obstacles, 0.0).any()
    component = np.tile(kinematic.node_component, LAYERS)
    labels = regions.label[grid_row]
    for piece in np.unique(labels[labels >= 0]):
        assert len(np.unique(component[labels == piece])) == 1
    assert (regions.length_rad > 0).all() and regions.length_rad.sum() <= 1.0 + 1e-12


def test_a_free_nodes_configuration_lies_on_its_piece(
    case: tuple[ServedModel, CoalModel, SceneTarget, FreeRegions, np.ndarray],
) -> None:
    model, _, _, regions, _ = case
    on_piece = np.flatnonzero(regions.label >= 0)[::50]
    found = regions.pieces_of(regions.q_rad[on_piece], model.limits.periodic)
    np.testing.assert_array_equal(found, regions.label[on_piece])
    assert len(regions.length_rad) >= 2 and regions.asked.sum() >= 2
