"""Leave-one-group-out selection in ``fgcd bench changes``: a group never chooses its own constants."""

from fgcd_cli.bench.changes.main import leave_one_group_out, leave_one_group_out_score_constants


def _group(name, scores_by_key, metric):
    return {
        "group": name,
        "kind": "Db",
        "changed_fraction_true": 0.01,
        "grid": {
            key: {metric: value, "best_f1": value, "ap": value, "auto_f1": value, "auto_recall": value}
            for key, value in scores_by_key.items()
        },
        "score_variants": {key: {"best_f1": value, "ap": value} for key, value in scores_by_key.items()},
    }


def test_held_out_group_is_scored_with_the_constants_the_others_prefer():
    a, b = ("acontrario", 0.005, 0.3), ("acontrario", 0.01, 0.2)
    # Group g0 alone prefers b (0.9 vs 0.1); the four others prefer a (0.6 vs 0.5).
    groups = [_group("g0", {a: 0.1, b: 0.9}, "auto_f1")] + [
        _group(f"g{i}", {a: 0.6, b: 0.5}, "auto_f1") for i in range(1, 5)
    ]
    rows = leave_one_group_out(groups, [a, b])
    assert rows[0]["group"] == "g0" and rows[0]["auto_f1"] == 0.1  # chosen without g0: a
    assert rows[0]["chosen"] == {"decision": "acontrario", "seed_p": 0.005, "extent_fraction": 0.3}
    # Each of the others is chosen on g0 and three like itself: mean 0.6*3+0.1 = 1.9 vs 0.5*3+0.9 = 2.4 -> b.
    assert all(row["auto_f1"] == 0.5 for row in rows[1:])


def test_score_constants_are_chosen_on_the_other_groups():
    shipped, wide = (12.0, 2.0), (24.0, 2.0)
    others = [_group(f"g{i}", {shipped: 0.7, wide: 0.6}, "best_f1") for i in range(1, 4)]
    groups = [_group("g0", {shipped: 0.2, wide: 0.8}, "best_f1")] + others
    out = leave_one_group_out_score_constants(groups)
    first = out["groups"][0]
    assert (first["gain_sigma_px"], first["smooth_sigma_px"]) == shipped and first["best_f1"] == 0.2
    # Each other group is chosen on g0 and two like itself: (0.2 + 1.4) / 3 < (0.8 + 1.2) / 3 -> wide, 0.6.
    assert [row["gain_sigma_px"] for row in out["groups"][1:]] == [24.0] * 3
    assert abs(out["logo_best_f1_all_constants"] - (0.2 + 0.6 * 3) / 4) < 1e-12


def test_without_score_variants_there_is_no_all_constants_figure():
    groups = [_group("g0", {}, "best_f1"), _group("g1", {}, "best_f1")]
    assert leave_one_group_out_score_constants(groups) is None


def test_per_kind_means_and_counts_pool_each_kind_alone():
    from fgcd_cli.bench.changes.main import _per_kind

    def row(kind, f1, true, found, false):
        return {
            "kind": kind,
            "best_f1": f1,
            "ap": f1,
            "auto_f1": f1,
            "changes_true": true,
            "changes_found": found,
            "false_regions": false,
        }

    out = _per_kind([row("Db", 0.8, 10, 9, 1), row("Db", 0.6, 30, 15, 3), row("Ds", 0.2, 4, 4, 20)])
    assert out["Db"]["groups"] == 2 and abs(out["Db"]["auto_f1"] - 0.7) < 1e-12
    assert out["Db"]["changes_found_fraction"] == 24 / 40  # pooled over the kind's changes, not averaged
    assert out["Db"]["false_regions_per_pair"] == 2.0
    assert out["Ds"]["false_regions_per_pair"] == 20.0 and out["Ds"]["changes_found_fraction"] == 1.0


def test_leave_one_kind_out_chooses_on_the_other_kinds_only():
    a, b = ("acontrario", 0.005, 0.3), ("acontrario", 0.01, 0.2)
    # Two Db groups prefer b strongly; the one Ds group prefers a. Leave one group out, Db-1 would
    # be chosen on Db-2 and Ds-1 (b wins); leave one kind out, only on Ds-1 (a wins).
    groups = [_group("Db-1", {a: 0.2, b: 0.9}, "auto_f1"), _group("Db-2", {a: 0.2, b: 0.9}, "auto_f1")]
    statue = _group("Ds-1", {a: 0.7, b: 0.6}, "auto_f1")
    statue["kind"] = "Ds"
    groups.append(statue)
    by_group = leave_one_group_out(groups, [a, b])
    by_kind = leave_one_group_out(groups, [a, b], by="kind")
    assert by_group[0]["auto_f1"] == 0.9 and by_kind[0]["auto_f1"] == 0.2
    assert by_kind[2]["auto_f1"] == 0.6  # the statue, chosen on the two test blocks: b
