"""The RF world: link budget, blockage, beams, noise, quantisation and driver quirks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.rf.link_budget import link_budget
from rfsas_hw.twin.rfworld import combine_chains, fading_db, segment_crossings
from rfsas_hw.twin.world import CHAIN_NOT_HEARD, CHAIN_SENTINEL, World

from .conftest import small, small_mapping


def _brute_crossings(p0, p1, rects, steps=4001):
    s = np.linspace(0, 1, steps)[1:-1]
    pts = p0[:, None, :] + s[None, :, None] * (p1 - p0)[:, None, :]
    x, y = pts[..., 0][..., None], pts[..., 1][..., None]
    inside = (x > rects[:, 0]) & (x < rects[:, 1]) & (y > rects[:, 2]) & (y < rects[:, 3])
    return inside.any(axis=1)


def test_segment_crossings_match_dense_sampling() -> None:
    rng = np.random.default_rng(0)
    rects = np.array([[0, 4, 0, 2], [5, 6, -3, 3], [-4, -1, -4, -1]], float)
    p0 = rng.uniform(-8, 8, (400, 2))
    p1 = rng.uniform(-8, 8, (400, 2))
    got = segment_crossings(p0, p1, rects)
    want = _brute_crossings(p0, p1, rects)
    # dense sampling can miss a corner clip thinner than its step; allow none of the other kind
    assert np.all(want <= got)
    assert np.mean(got != want) < 0.01


def test_segment_crossings_edge_cases() -> None:
    rect = np.array([[0.0, 2.0, 0.0, 2.0]])
    p0 = np.array([[-1, 1], [-1, 0], [-1, 1], [1, 1], [-1, -1], [3, 3]], float)
    p1 = np.array([[3, 1], [3, 0], [-0.5, 1], [1, 5], [3, 3], [4, 4]], float)
    # through, along an edge, stops short, starts inside, diagonal through, away
    assert segment_crossings(p0, p1, rect)[:, 0].tolist() == [True, False, False, True, True, False]


def test_fading_mean_power_and_chain_correlation() -> None:
    rng = np.random.default_rng(1)
    f = fading_db(200_000, "rayleigh", 0.0, 0.9, rng)
    p = 10 ** (f / 10)
    assert p.mean(axis=0) == pytest.approx([1.0, 1.0], abs=0.01)
    # |ρ|² is the correlation of the powers of two correlated Rayleigh chains
    assert np.corrcoef(p[:, 0], p[:, 1])[0, 1] == pytest.approx(0.81, abs=0.01)
    ric = 10 ** (fading_db(200_000, "rician", 10.0, 0.0, rng) / 10)
    assert ric.mean() == pytest.approx(1.0, abs=0.01)
    assert ric.std() < p.std() / 2
    assert np.all(fading_db(5, "none", 0, 0, rng) == 0)


def test_combined_signal_quirks() -> None:
    chains = np.array([[-60.0, -63.0], [-60.0, -60.0], [np.nan, -70.0], [np.nan, np.nan]])
    np.testing.assert_allclose(combine_chains(chains, "max")[:3], [-60, -60, -70])
    ps = combine_chains(chains, "power-sum")
    assert ps[1] == pytest.approx(-60 + 10 * math.log10(2))
    assert ps[2] == pytest.approx(-70)
    assert np.isnan(ps[3]) and np.isnan(combine_chains(chains, "max")[3])


def test_low_detail_equals_the_link_budget_through_the_beams() -> None:
    sc = small(detail="low")
    rec = World(sc).receptions("rsu")
    assert len(rec) > 20
    lb = link_budget(rec.distance_m, "wifi", pt_dbm=20.0, gr_dbi=0.0)
    phone = rec.emitter == 1
    ant = World(sc).antennas["rsu"]
    want = lb.rx_power_dbm[:, None] + ant.gains_db(rec.true_relative_deg)
    np.testing.assert_allclose(rec.chain_dbm[phone], want[phone], atol=1e-9)


def test_high_detail_quantises_and_blocks() -> None:
    data = small_mapping()
    data["sensors"][0]["pose"] = {"x_m": 0, "y_m": -40, "heading_deg": 0}
    data["duration_s"] = 12.0
    world = World(small(**{k: v for k, v in data.items() if k != "version"}, version=1))
    rec = world.receptions("rsu")
    present = np.isfinite(rec.chain_dbm)
    assert np.all(rec.chain_dbm[present] == np.round(rec.chain_dbm[present]))
    # the walker starts behind the building (seen from the south) and walks out of it
    phone = rec.emitter == 1
    assert rec.blocked[phone].any() and not rec.blocked[phone].all()
    # blocked frames come in weaker than the noise-free link budget by the building's 20 dB
    low = World(world.scenario, detail="low").receptions("rsu")
    _, i_high, i_low = np.intersect1d(rec.t_s, low.t_s, return_indices=True)
    loss = low.chain_dbm[i_low] - rec.chain_dbm[i_high]
    blocked = rec.blocked[i_high]
    assert np.nanmean(loss[blocked]) == pytest.approx(20.0, abs=1.0)
    assert np.nanmean(loss[~blocked]) == pytest.approx(0.0, abs=1.0)


def test_sentinel_chains_and_single_chain_cards() -> None:
    rec = World(small()).receptions("rsu")
    lost = rec.chain_state == CHAIN_SENTINEL
    assert 0 < lost.any(axis=1).mean() < 0.15
    assert np.all(np.isnan(rec.chain_dbm[lost]))
    obs = rec.observations()
    assert np.isnan(obs.rssi_dbm).any(axis=1).sum() == lost.any(axis=1).sum()

    data = small_mapping()
    data["sensors"][0]["receiver"] = "two-single-chain-cards"
    data["sensors"][0]["pose"] = {"x_m": -60, "y_m": 0, "heading_deg": 34}
    two = World(small(**{k: v for k, v in data.items() if k != "version"}, version=1))
    rec2 = two.receptions("rsu")
    assert rec2.n_cards == 2 and rec2.heard.shape[1] == 2
    # the phone sits 60° off boresight: the weaker beam's card misses frames the other hears
    assert (rec2.chain_state == CHAIN_NOT_HEARD).any()
    assert np.all(rec2.heard == (rec2.chain_state != CHAIN_NOT_HEARD))
    card0 = rec2.observations(card=0)
    assert card0.n_antennas == 1 and len(card0) == rec2.heard[:, 0].sum()


def test_scan_plan_limits_what_is_heard() -> None:
    data = small_mapping()
    data["sensors"][0]["scan"] = {"channels": [1, 6, 11], "dwell_ms": 200}
    hop = World(small(**{k: v for k, v in data.items() if k != "version"}, version=1))
    rec = hop.receptions("rsu")
    fixed = World(small()).receptions("rsu")
    assert 0.2 < len(rec) / len(fixed) < 0.5
    slot = np.floor(rec.t_s / 0.2).astype(int) % 3
    assert np.all(slot == 1)  # channel 6 is the second of three dwells


def test_medium_detail_noise_matches_the_snr_formula() -> None:
    from rfsas_hw.rf.aoa import sigma_monopulse_deg

    world = World(small(detail="medium", duration_s=60.0))
    rec = world.receptions("rsu")
    low = World(small(detail="low", duration_s=60.0)).receptions("rsu")
    ant = world.antennas["rsu"]
    diff_err = (rec.chain_dbm[:, 0] - rec.chain_dbm[:, 1]) - (
        low.chain_dbm[:, 0] - low.chain_dbm[:, 1]
    )
    angle_err = diff_err / ant.difference_slope_db_per_deg()
    want = sigma_monopulse_deg(low.snr_db.max(axis=1), beamwidth_deg=60.0)
    z = angle_err / want
    assert np.std(z) == pytest.approx(1.0, abs=0.1)


def test_same_seed_same_world_other_seed_differs() -> None:
    a = World(small()).receptions("rsu")
    b = World(small()).receptions("rsu")
    c = World(small(seed=6)).receptions("rsu")
    np.testing.assert_array_equal(a.chain_dbm, b.chain_dbm)
    np.testing.assert_array_equal(a.capture_ns, b.capture_ns)
    assert len(a) != len(c) or not np.array_equal(a.t_ns, c.t_ns)
