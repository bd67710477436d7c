"""The rows of ``experiment=localization`` (absolute localization against a map: the survey's outlook; Micro-GPS,
Zhang et al. ICRA 2019): one per query and map size, with every metric the evaluation computes and its own. Its
identity columns: the query image, whether its floor is in the map (0: a foreign floor that must be rejected), the
map's size, and the estimated pose in map coordinates (map px of the query's centre; degrees, atan2(P[1, 0],
P[0, 0]) of the image -> map pose; NaN when none)."""
from __future__ import annotations

from gtsweep.evaluation.schema import EVALUATED, Metric, Rows

META = ("query", "in_map", "map_images", "est_x", "est_y", "est_theta")
#: Its own metrics (a query's; the map's).
METRICS = (
    Metric("localized", "share", "queries whose pose was accepted (experiment.min_inliers, min_inlier_ratio)",
           aggregation="rate"),
    Metric("localization_success", "share", "in-map queries with ground truth localized within 30 px and "
           "1.5 deg in map px (Micro-GPS' rule)", aggregation="rate", interval=True),
    Metric("false_localization", "share", "queries from a floor not in the map that were accepted (should "
           "be 0)", aggregation="rate", interval=True),
    Metric("wrong_localization", "share", "in-map queries accepted with a pose outside 30 px / 1.5 deg",
           aggregation="rate"),
    Metric("success_position_error", "px", "position error of the successful queries (map px)",
           per_view=lambda r: r["position_error"].where(r["localization_success"] == 1), digits=2),
    Metric("success_orientation_error", "deg", "orientation error of the successful queries",
           per_view=lambda r: r["orientation_error"].where(r["localization_success"] == 1), digits=3),
    Metric("n_voted", "matches", "matches kept by the voting step (all matches without voting)", digits=1),
    Metric("inlier_ratio", "share", "inliers / matches given to the estimator", reported=False),
    Metric("t_vote", "s", "voting time per query", digits=4, reported=False),
    Metric("t_query", "s", "time per query: detection, description, matching, voting, pose", digits=3,
           interval=True),
    Metric("t_index", "s", "building the matcher's index of the map (once per map)", digits=3,
           reported=False),
    Metric("map_features", "features", "features in the map", digits=0),
    Metric("map_bytes", "bytes", "memory of the map's features: descriptors, positions, orientations, ids",
           digits=0),
    Metric("map_bytes_per_m2", "bytes/m2", "map memory per m2 of floor covered (data set's px/mm)",
           digits=0),
    Metric("map_build_s", "s", "map build time: detection and description of every mapping image",
           digits=2),
)
HEADLINE = "localization_success"
LOCALIZATION = Rows((*EVALUATED, *METRICS), HEADLINE, curves=(HEADLINE, "t_query"), meta=META, step="map_images")
