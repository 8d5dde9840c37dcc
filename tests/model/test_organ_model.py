"""OrganModel: valid samples, seeds, checkpoints, growth, and plausible yet new plants on a small population."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from torch4dtree.data.synthetic import synthetic_plant
from torch4dtree.model import donors, organs
from torch4dtree.model.checkpoint import CheckpointError, load, save_model
from torch4dtree.model.fourd import sequence_validity
from torch4dtree.model.organ_forecast import forecast_organs
from torch4dtree.model.organs import OrganModel
from torch4dtree.trees.structures import TreeSequence

KIND = "bean"


@pytest.fixture(scope="module")
def population() -> tuple[list[TreeSequence], list[TreeSequence]]:
    plants = [synthetic_plant(KIND, seed, n_frames=4, T=16).sequence for seed in range(16)]
    return plants[:8], plants[8:]


@pytest.fixture(scope="module")
def model(population: tuple[list[TreeSequence], list[TreeSequence]]) -> OrganModel:
    return OrganModel().fit(population[0])


def morphometrics(plants: list[TreeSequence]) -> torch.Tensor:
    """``(P, 6)`` log(1 + x) of total length, height and branch count at the middle and the last frame."""
    rows = []
    for p in plants:
        feats = []
        for j in (len(p) // 2, len(p) - 1):
            f = p.frames[j]
            feats += [float(f.total_length()[0]), float(f.height()[0]), float(f.num_branches[0])]
        rows.append(feats)
    return torch.tensor(rows, dtype=torch.float64).log1p()


def plausible(samples: list[TreeSequence], real: list[TreeSequence]) -> bool:
    """Medians within 0.5-2x of the real plants' and a spread at least a third of theirs, feature by feature."""
    s, r = morphometrics(samples).expm1(), morphometrics(real).expm1()
    ratio = s.median(0).values / r.median(0).values
    spread = morphometrics(samples).std(0) / morphometrics(real).std(0).clamp_min(1e-9)
    return bool(((ratio > 0.5) & (ratio < 2.0)).all() and (spread > 1 / 3).all())


def novel(samples: list[TreeSequence], train: list[TreeSequence], real: list[TreeSequence]) -> bool:
    """Samples are as far from their nearest training plant as new real plants are (at least a third as far)."""
    t = morphometrics(train)
    scale = t.std(0).clamp_min(1e-9)

    def nearest(x: torch.Tensor) -> torch.Tensor:
        return torch.cdist(x / scale, t / scale).min(1).values.median()

    return bool(nearest(morphometrics(samples)) > nearest(morphometrics(real)) / 3)


def test_samples_are_valid_trees(model: OrganModel) -> None:
    plants = model.sample(12, generator=torch.Generator().manual_seed(1))
    for p in plants:
        assert sequence_validity(p) == []
        assert torch.isfinite(p.frames.points).all()
        assert (p.frames.branch_lengths() > 0).all()
        assert len(p) == len(model.ages)


def test_sample_keys_stay_bounded(population: tuple[list[TreeSequence], list[TreeSequence]],
                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Deep hierarchies would open keys exponentially in their depth: the bound holds and the samples stay valid."""
    full = len(OrganModel().fit(population[0]).sample_keys()[0])
    bound = len(OrganModel().fit(population[0]).keys) + 3
    assert full > bound  # the bound bites
    monkeypatch.setattr(organs, "MAX_SAMPLE_KEYS", bound)
    model = OrganModel().fit(population[0])
    assert len(model.sample_keys()[0]) == bound
    for p in model.sample(6, generator=torch.Generator().manual_seed(2)):
        assert sequence_validity(p) == []
        assert int(p.frames.label.max()) < bound


def test_seeds_reproduce_and_checkpoint_round_trips(model: OrganModel, tmp_path: Path) -> None:
    a = model.sample(3, generator=torch.Generator().manual_seed(5))
    b = model.sample(3, generator=torch.Generator().manual_seed(5))
    assert all(torch.equal(x.frames.points, y.frames.points) for x, y in zip(a, b))
    z = model.sample_coefficients(3, torch.Generator().manual_seed(5))
    alone = model.decode(z[1:2])[0]
    assert torch.equal(alone.frames.points, a[1].frames.points)
    loaded = load(model.save(tmp_path / "organs.pt", {"note": "organs"}))
    assert isinstance(loaded, OrganModel) and loaded.settings == model.settings
    assert loaded.checkpoint_config == {"note": "organs"}
    raw = torch.load(tmp_path / "organs.pt", weights_only=True)
    assert raw["format"] == "torch4dtree.OrganModel" and raw["version"] == 1
    assert raw["args"] == model.settings.to_dict()
    c = loaded.sample(3, generator=torch.Generator().manual_seed(5))
    assert all(torch.equal(x.frames.points, y.frames.points) for x, y in zip(a, c))
    assert loaded.keys == model.keys


def test_plants_decoded_together_equal_plants_decoded_alone(model: OrganModel, monkeypatch: pytest.MonkeyPatch
                                                            ) -> None:
    monkeypatch.setattr(organs, "DECODE_CHUNK", 2)  # chunk boundaries inside the batch
    z = model.sample_coefficients(5, torch.Generator().manual_seed(6))
    together = model.decode(z)
    for i, plant in enumerate(together):
        alone = model.decode(z[i:i + 1])[0]
        for name in ("points", "parent", "s", "num_branches", "label"):
            assert torch.equal(getattr(alone.frames, name), getattr(plant.frames, name)), name
    again = model.decode(z)
    assert all(torch.equal(a.frames.points, b.frames.points) for a, b in zip(together, again))


def test_children_keep_their_parents_present() -> None:
    # the child (key 2) is there at every age, its parent (key 1) only in the middle one: carried to the last age
    # and there from the first, at its first size (the child's plant grew it earlier than the parent's plant)
    sizes = torch.tensor([[[1.0, 2.0, 3.0], [0.0, 0.5, 0.0], [0.2, 0.2, 0.2]]], dtype=torch.float64)
    carried = organs.carry_parents(sizes, torch.tensor([-1, 0, 1]), [0, 1, 2])
    assert carried[0, 1].tolist() == [0.5, 0.5, 0.5] and torch.equal(carried[0, [0, 2]], sizes[0, [0, 2]])
    up = torch.linspace(0, 1, 4, dtype=torch.float64)[:, None] * torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    shape = up.expand(3, 3, 4, 3)
    s = torch.full((3, 3), 0.5, dtype=torch.float64)
    plant = organs.assemble_batch(torch.zeros(3, dtype=torch.long), torch.arange(3), torch.tensor([-1, 0, 1]),
                                  carried[0], shape, s, torch.arange(3.0), ["p"])[0]
    assert plant.frames.num_branches.tolist() == [3, 3, 3]
    alone = sizes.clone()
    alone[0, 2] = 0.0  # no child: a parent is not carried for nothing
    assert organs.carry_parents(alone, torch.tensor([-1, 0, 1]), [0, 1, 2])[0, 1].tolist() == [0.0, 0.5, 0.0]


@pytest.mark.parametrize("fail", [False, True])
def test_decode_restores_the_callers_threads(model: OrganModel, fail: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        if fail:  # restored on an error too
            monkeypatch.setattr(OrganModel, "_frames", lambda *args: (_ for _ in ()).throw(RuntimeError("boom")))
            with pytest.raises(RuntimeError, match="boom"):
                model.sample(2, generator=torch.Generator().manual_seed(0))
        else:
            model.sample(2, generator=torch.Generator().manual_seed(0))
        assert torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)


def test_organ_checkpoints_fail_clearly(model: OrganModel, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="not fitted"):
        save_model(OrganModel(), tmp_path / "empty.pt")
    with pytest.raises(TypeError, match="OrganModel"):
        save_model(torch.nn.Linear(2, 2), tmp_path / "linear.pt")  # type: ignore[arg-type]
    raw = torch.load(save_model(model, tmp_path / "good.pt"), weights_only=True)
    torch.save({**raw, "args": {"n_t": 8}}, tmp_path / "paper_args.pt")  # the paper model's settings
    torch.save({**raw, "state_dict": {}}, tmp_path / "no_state.pt")
    for name in ("paper_args", "no_state"):
        with pytest.raises(CheckpointError, match=name):
            load(tmp_path / f"{name}.pt")


def test_organs_grow_and_vanish_no_more_than_in_training(model: OrganModel) -> None:
    events = seen = 0
    for p in model.sample(12, generator=torch.Generator().manual_seed(2)):
        lengths = torch.zeros(len(p), len(model.sample_keys()[0]), dtype=torch.float64)  # (frames, keys)
        for j in range(len(p)):
            f = p.frames[j]
            lengths[j, f.label] = f.branch_lengths().to(torch.float64)
        alive = lengths > 0
        both = alive[:-1] & alive[1:]
        assert (lengths[1:][both] >= lengths[:-1][both] - 1e-9).all()  # an organ never shrinks while it lives
        events += int((alive[:-1] & ~alive[1:]).sum())
        seen += int(alive[:-1].sum())
    train_alive = model.growth > 0  # the training organs on the same ages
    train_rate = float((train_alive[:, :-1] & ~train_alive[:, 1:]).sum()) / float(train_alive[:, :-1].sum())
    assert events / seen <= 1.5 * train_rate + 0.01


def test_plausible_and_new_where_the_mean_and_a_copy_are_not(
        model: OrganModel, population: tuple[list[TreeSequence], list[TreeSequence]]) -> None:
    train, held = population
    samples = model.sample(24, generator=torch.Generator().manual_seed(3))
    assert plausible(samples, held) and novel(samples, train, held)
    collapsed = [samples[0]] * len(samples)  # one plant for all: a model that has collapsed onto its mean
    assert not plausible(collapsed, held)
    assert not novel(train, train, held)  # memorising: the training plants themselves


def test_forecast_continues_an_observed_plant(
        model: OrganModel, population: tuple[list[TreeSequence], list[TreeSequence]]) -> None:
    plant = population[1][0]
    future = forecast_organs(model, plant[[0, 1]], n=3, generator=torch.Generator().manual_seed(4))
    seen = float(plant.frames[1].total_length()[0])
    for f in future:
        assert sequence_validity(f) == []
        assert float(f.times[0]) > float(plant.times[1])
        grown = f.frames.total_length()
        assert float(grown[0]) >= 0.9 * seen and (grown[1:] >= grown[:-1] - 1e-6).all()
        assert 0.5 < float(grown[-1]) / float(plant.frames[-1].total_length()[0]) < 2.0


def test_samples_stand_as_the_training_plants_stand(population: tuple[list[TreeSequence], list[TreeSequence]]
                                                    ) -> None:
    """A sample keeps its donor's orientation about the vertical (the ground metric registers plants without
    rotation): copying one plant whole (no switch, no length noise), each organ of a sample points as a training
    organ does, not turned by a random angle."""
    from torch4dtree.model.organ_table import azimuth
    from torch4dtree.settings import OrganSettings

    m = OrganModel(OrganSettings(persistence=1.0, jitter=0.0)).fit(population[0])
    keys = m.sample_keys()[0]
    for sample in m.sample(6, generator=torch.Generator().manual_seed(0)):
        last = sample.frames[len(sample) - 1]
        for key in ((), (0,)):
            k = keys.index(key)
            rows = torch.nonzero(last.label == k).reshape(-1)
            assert len(rows) == 1
            mine = float(azimuth(last.points[int(rows[0])]))
            theirs = azimuth(m.shape[:, -1])  # a key copies an organ of its parent's donor, at any rank
            turned = torch.remainder(theirs - mine + torch.pi, 2 * torch.pi) - torch.pi
            assert float(turned.abs().min()) < 1e-6, key


def test_no_sampled_organ_outgrows_the_training_organs_it_stands_for(model: OrganModel) -> None:
    """The length jitter stays within the training organs that stand in for the copied one (itself included): a
    sample has no leaf longer than every real leaf at its place."""
    draw = model.grow(list(range(40)))
    present = draw.chosen >= 0
    r = draw.chosen[present]
    standing = torch.from_numpy(model.links().equivalent[r.numpy()])  # (N, P) the organs standing in for each
    log_longest = torch.where(standing >= 0, model.log_length[standing.clamp(min=0)], -torch.inf).amax(1)
    longest = log_longest.maximum(model.log_length[r]).exp()
    assert (draw.length[present] <= longest * (1 + 1e-12)).all()


def copies_of_one_plant(model: OrganModel, n: int) -> float:
    """The share of ``n`` samples (seeds 0 .. n-1) whose organs all come from one training plant."""
    draw = model.grow(list(range(n)))
    plant = torch.from_numpy(model.links().plant)
    whole = [len(torch.unique(plant[row[row >= 0]])) == 1 for row in draw.chosen]
    return sum(whole) / n


def test_a_few_training_plants_are_mixed_not_copied(population: tuple[list[TreeSequence], list[TreeSequence]],
                                                     monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Four training plants: a memoriser gives whole copies every time; the model's kernel widens until a sample
    draws on several plants, so few samples copy one plant whole (a fixed width of 0.6 sd: about 40 %). The width
    is a function of the fitted plants: a checkpoint gives it back, and seeds reproduce."""
    m = OrganModel().fit(population[0][:4])
    assert copies_of_one_plant(m, 40) <= 0.2  # a memoriser: 1.0
    assert m.donor_bandwidth() > m.settings.bandwidth
    assert donors.effective_donors(m.summary, m.donor_bandwidth()) >= donors.MIN_DONORS - 1e-6
    save_model(m, tmp_path / "tiny.pt")
    back = load(tmp_path / "tiny.pt")
    assert back.donor_bandwidth() == m.donor_bandwidth()
    assert torch.equal(back.grow([5, 6]).chosen, m.grow([5, 6]).chosen)
    assert torch.equal(m.grow([5, 6]).length, m.grow([5, 6]).length)


def test_the_kernel_keeps_its_width_on_many_plants() -> None:
    """Forty plants spread as a Gaussian already give each sample several donors at ``settings.bandwidth``: the
    width stays; a quarter of them widens it."""
    latents = torch.randn(40, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    widths = []
    for n in (40, 10):
        m = OrganModel()
        m.keys, m.summary = [()], latents[:n]
        widths.append(m.donor_bandwidth())
    assert widths[0] == OrganModel().settings.bandwidth < widths[1]
