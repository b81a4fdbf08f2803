"""The background LRP the global search ranks places by (daemon/mapping/backgrounds.py,
design §9): each place's LRP in the other places' views, re-centred on the level of the
own-view estimates, measured by the mapper as places are learned."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest

from daemon.mapping.backgrounds import CROSS_VIEWS, Levels, levels, search_background, views_of
from daemon.mapping.place import Place
from daemon.mapping.settings import OdometryNoiseSettings
from daemon.service.mapper import Mapper
from daemon.store.sqlite_store import MapStore
from daemon.vision.recognition import FastMatcher, PreparedPanorama, PreparedTemplates
from kernel.panorama import to_grey
from tests.map_fixtures import synthetic_place


def test_a_place_averages_the_first_views_of_the_others_and_they_settle() -> None:
    ids = list(range(1, CROSS_VIEWS + 10))
    assert views_of(3, [1, 2, 3, 4]) == [1, 2, 4]
    assert views_of(3, ids) == [p for p in range(1, CROSS_VIEWS + 2) if p != 3]
    # once the map holds CROSS_VIEWS + 1 places, a new one joins no older place's views
    assert all(ids[-1] not in views_of(q, ids) for q in ids[:CROSS_VIEWS + 1])
    assert views_of(1, [1]) == []


def test_the_cross_estimate_is_re_centred_and_a_measured_background_wins() -> None:
    place = dataclasses.replace(synthetic_place(np.random.default_rng(1), "a"),
                                reference_panorama=None, background_estimate=0.9,
                                background_cross=0.88)
    other = dataclasses.replace(place, background_estimate=0.7, background_cross=0.84)
    map_levels = levels([place, other])
    assert map_levels == Levels(pytest.approx(0.8), pytest.approx(0.86))
    # its landmarks match the others' views 0.02 above the map's, so it stands 0.02
    # above the own-view level — not 0.1 above, as its own view (a look-alike in it) says
    assert search_background(place, map_levels) == pytest.approx(0.82)
    assert search_background(other, map_levels) == pytest.approx(0.78)
    assert search_background(place, None) == 0.9  # no level yet: its own view's
    measured = dataclasses.replace(place, background_lrp=0.6)
    assert search_background(measured, map_levels) == 0.6
    bare = dataclasses.replace(place, background_estimate=None, background_cross=None)
    assert search_background(bare, map_levels) is None
    assert levels([bare]) is None


def _assert_measured_in_each_others_views(store: MapStore, mapper: Mapper, ids: list[int],
                                          places: list[Place]) -> None:
    """Each place's cross background, stored and in the mapper's map, is its mean LRP in
    the other places' reference views."""
    matcher = FastMatcher()
    views = {p: PreparedPanorama.of(to_grey(store.reference_panorama(p))) for p in ids}
    for pid, place in zip(ids, places, strict=True):
        templates = PreparedTemplates.of(place.landmarks.templates())
        expected = np.mean([matcher.lrp(views[q], templates) for q in ids if q != pid])
        assert store.load().place(pid).background_cross == pytest.approx(expected)
        assert mapper.graph.place(pid).background_cross == pytest.approx(expected)


def test_the_mapper_measures_each_place_in_the_others_views(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    places = [synthetic_place(rng, label) for label in ("a", "b", "c")]
    with MapStore.open(tmp_path / "map.db", "abc123") as store:
        mapper = Mapper(store, OdometryNoiseSettings())
        first, _ = mapper.add_place(places[0], [])
        assert mapper.measure_cross_backgrounds(first.id) == []  # no other view yet
        assert store.load().place(first.id).background_cross is None
        ids = [first.id]
        for place in places[1:]:
            stored, _ = mapper.add_place(place, [])
            ids.append(stored.id)
            changed = mapper.measure_cross_backgrounds(stored.id)
            assert sorted(p.id for p in changed) == ids  # every view set it joins
        _assert_measured_in_each_others_views(store, mapper, ids, places)


def test_a_map_stored_without_cross_backgrounds_gets_them_when_opened(tmp_path: Path) -> None:
    """An older map (its places stored before cross backgrounds were kept): the mapper
    measures them once when it opens the map, each as measured place by place."""
    rng = np.random.default_rng(6)
    places = [synthetic_place(rng, label) for label in "abc"]
    with MapStore.open(tmp_path / "map.db", "abc123") as store:
        ids = [store.add_place(place).id for place in places]
        assert all(p.background_cross is None for p in store.load().places)
        mapper = Mapper(store, OdometryNoiseSettings())
        _assert_measured_in_each_others_views(store, mapper, ids, places)


def test_a_new_view_is_added_to_the_means_it_joins_and_a_full_set_is_left_alone(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With views limited to 2 other places, the third place learned joins the first
    two's views (one LRP added to each mean) and later ones join none: every mean is
    the one measured over its views from scratch."""
    import daemon.service.mapper as mapper_module

    monkeypatch.setattr(mapper_module, "views_of", functools.partial(views_of, limit=2))
    rng = np.random.default_rng(5)
    places = [synthetic_place(rng, label) for label in "abcde"]
    with MapStore.open(tmp_path / "map.db", "abc123") as store:
        mapper = Mapper(store, OdometryNoiseSettings())
        ids, changes = [], []
        for place in places:
            stored, _ = mapper.add_place(place, [])
            ids.append(stored.id)
            changes.append(sorted(p.id for p in mapper.measure_cross_backgrounds(stored.id)))
        assert changes == [[], ids[:2], ids[:3], [ids[3]], [ids[4]]]
        matcher = FastMatcher()
        views = {p: PreparedPanorama.of(to_grey(store.reference_panorama(p))) for p in ids}
        for pid, place in zip(ids, places, strict=True):
            templates = PreparedTemplates.of(place.landmarks.templates())
            expected = np.mean([matcher.lrp(views[q], templates)
                                for q in views_of(pid, ids, limit=2)])
            assert store.load().place(pid).background_cross == pytest.approx(expected)


def test_an_lrp_in_another_places_view_is_measured_once_and_the_memo_is_bounded(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Mapper.lrps_in_view gives what the matcher gives, reads a view's panorama only
    for what it has not measured (a learn asks for its own landmarks in its cross
    background's views and again in its look-alike candidates'), and keeps LRPS_KEPT."""
    import daemon.service.mapper as mapper_module

    rng = np.random.default_rng(8)
    places = [synthetic_place(rng, label) for label in "abcd"]
    with MapStore.open(tmp_path / "map.db", "abc123") as store:
        ids = [store.add_place(place).id for place in places]
        Mapper(store, OdometryNoiseSettings())  # measures and stores the cross backgrounds
        mapper = Mapper(store, OdometryNoiseSettings())  # so this one has measured nothing
        monkeypatch.setattr(mapper_module, "LRPS_KEPT", 3)
        prepared: list[int] = []
        real_of = PreparedPanorama.of
        monkeypatch.setattr(mapper_module.PreparedPanorama, "of",
                            lambda grey: prepared.append(1) or real_of(grey))
        view = PreparedPanorama.of(to_grey(store.reference_panorama(ids[0])))
        prepared.clear()
        expected = [FastMatcher().lrp(view, PreparedTemplates.of(p.landmarks.templates()))
                    for p in places[1:3]]
        assert mapper.lrps_in_view(ids[0], ids[1:3]) == pytest.approx(expected)
        assert prepared == [1]
        assert mapper.lrps_in_view(ids[0], ids[1:3][::-1]) == pytest.approx(expected[::-1])
        assert prepared == [1]  # both measured before: the panorama is not read again
        mapper.lrps_in_view(ids[1], [ids[2], ids[3]])  # two more: the one used least goes
        assert mapper.lrps_in_view(ids[0], [ids[2]]) == pytest.approx(expected[1:])
        assert prepared == [1, 1, 1]
