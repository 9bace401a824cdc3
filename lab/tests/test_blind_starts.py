"""lab/blind_starts.py's counts on hand-made episodes whose answers are known."""

import numpy as np
import pytest

from lab import blind_starts  # noqa: E402


def test_summarise_counts_blind_starts_lost_per_policy_and_per_target():
    blind = {"a": np.array([True, False, False, True]), "b": np.array([False, True, False])}
    lost = [
        {"a": np.array([True, True, False, False]), "b": np.array([False, True, True])},  # policy 0
        {"a": np.array([False, False, False, False]), "b": np.array([False, True, False])},
    ]  # policy 1
    action = {"a": np.array([[1, 2, 3, 4], [5, 6, 7, 8]]), "b": np.array([[0, 9, 10], [6, 6, 6]])}  # [S=2, N]
    unseen = {
        "a": np.array([[True, False, False, True], [False, False, False, True]]),
        "b": np.array([[False, True, False], [False, True, False]]),
    }
    flown = [
        {n: {"blind": blind[n], "lost": row[n], "action": action[n] + k, "unseen": unseen[n]} for n in blind}
        for k, row in enumerate(lost)
    ]
    s = blind_starts.summarise(flown, ("a", "b"))
    assert (s["episodes"], s["blind_starts"]) == (7, 3)
    assert s["blind_lost_per_policy"] == [2, 1] and s["seen_lost_per_policy"] == [2, 0]
    # blind episodes 0, 3 (a) and 5 (b): lost by 1 of 2, 0 of 2 and 2 of 2 policies
    assert s["blind_lost_share"] == pytest.approx((0.5 + 0.0 + 1.0) / 3)
    assert s["ci95"][0] <= s["blind_lost_share"] <= s["ci95"][1]
    assert s["per_target"]["a"] == {"blind_starts": 2, "blind_lost": [1, 0], "seen_lost": [1, 0]}
    assert s["per_target"]["b"] == {"blind_starts": 1, "blind_lost": [1, 1], "seen_lost": [1, 0]}
    assert s["blind_episodes"] == [0, 3, 5] and s["lost_episodes_per_policy"] == [[0, 1, 5, 6], [5]]
    # the unseen steps' commands: a 1, 4, 8 and b 9, 6 (policy 1 adds 1 to each)
    assert s["actions_before_first_sight_per_policy"] == [
        [0, 1, 0, 0, 1, 0, 1, 0, 1, 1, 0],
        [0, 0, 1, 0, 0, 1, 0, 1, 0, 1, 1],
    ]


def test_compare_gives_the_paired_change_in_the_share_lost():
    base = {"targets": ["a"], "episodes_per_target": 4, "seed": 0, "episodes": 4, "blind_episodes": [0, 3]}
    before = {**base, "lost_episodes_per_policy": [[0, 1], [0]]}  # shares [1, 0.5, 0, 0]
    after = {**base, "lost_episodes_per_policy": [[3], []]}  # shares [0, 0, 0, 0.5]
    change = blind_starts.compare(before, after)
    assert change["blind_starts"]["before"] == 0.5 and change["blind_starts"]["after"] == 0.25
    assert change["blind_starts"]["difference"] == pytest.approx(-0.25)
    assert change["all_episodes"]["difference"] == pytest.approx((-1 - 0.5 + 0 + 0.5) / 4)
    with pytest.raises(SystemExit, match="different episodes"):
        blind_starts.compare(before, {**after, "seed": 1})


def _record(flown, names, first=0):
    return {
        "policies": [f"p{k}" for k in range(first, first + len(flown))],
        "targets": list(names),
        "episodes_per_target": 0,
        "seed": 0,
        **blind_starts.summarise(flown, names),
    }


def test_merge_of_two_records_is_the_record_of_all_their_policies_flown_at_once():
    """Seeds 0-4 and 5-9 written apart and merged give the counts, shares and interval of the ten flown together."""
    rng = np.random.default_rng(0)
    names = ("a", "b")
    blind = {n: rng.random(30) < 0.3 for n in names}
    flown = [
        {
            n: {
                "blind": blind[n],
                "lost": rng.random(30) < 0.4,
                "action": rng.integers(0, 11, (3, 30)),
                "unseen": rng.random((3, 30)) < 0.5,
            }
            for n in names
        }
        for _ in range(5)
    ]
    merged = blind_starts.merge([_record(flown[:2], names), _record(flown[2:], names, first=2)])
    together = _record(flown, names)
    assert merged.keys() == together.keys()
    for key, value in together.items():
        if key == "ci95":  # a bootstrap over the same shares, its draws in the same order
            np.testing.assert_allclose(merged[key], value)
        else:
            assert merged[key] == value, key
    with pytest.raises(SystemExit, match="different episodes"):
        blind_starts.merge([_record(flown[:2], names), {**_record(flown[2:], names), "seed": 1}])
