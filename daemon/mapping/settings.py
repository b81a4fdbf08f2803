"""Settings of place learning (Turn Back and Look, docs/design.md §3)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from kernel.settings import setting


@dataclass(frozen=True)
class TblSettings:
    extent_m: float = setting(0.5, gt=0.0, le=2.0, doc="cross arm: out and back along ±x, ±y")
    speed_m_s: float = setting(0.2, gt=0.0, le=1.0, doc="speed along the cross")
    candidates: int = setting(32, ge=4, le=64, doc="statically selected candidates (§4.2)")
    keep: int = setting(16, ge=1, le=64, doc="landmarks kept: those with the best "
                        "recognition margin over the cross (§4.3; daemon/mapping/tbl.py)")
    margin_every: int = setting(4, ge=1, le=100, doc="every n-th frame of the cross, each "
                                "candidate's best look-alike is searched for in the panorama")
    margin_cap: float = setting(0.2, gt=0.0, le=2.0, doc="a candidate's margin over its "
                                "best look-alike counts up to this NCC: beyond it it is "
                                "unmistakable, and being more so should not outrank being "
                                "reliably so")
    light_change: float = setting(0.5, ge=0.0, lt=1.0, doc="the kept set must stay "
                                  "recognisable with the light this fraction brighter or "
                                  "dimmer: each template matched against itself so changed, "
                                  "pixels clipped, the set's mean NCC must reach light_ncc")
    light_ncc: float = setting(0.95, ge=0.0, le=1.0, doc="see light_change; candidates "
                               "that hold up replace those that suffer most until it does")
    frame_timeout_s: float = setting(2.0, gt=0.0, le=30.0, doc="no frame this long: refuse")
    move_timeout_s: float = setting(20.0, gt=0.0, le=300.0, doc="one arm may take this long")
    path_tolerance_m: float = setting(0.1, gt=0.0, le=1.0, doc="a leg the base calls done "
                                      "must have been driven to this (or half the extent, if "
                                      "less) by its odometry, else learning fails: a place is "
                                      "never learned from a path it did not drive")
    turn_tolerance_rad: float = setting(0.1, gt=0.0, le=1.0, doc="likewise for the heading "
                                        "each leg must end with (a differential base's turns; "
                                        "0 for the others)")
    window_cols: int = setting(12, ge=2, le=64, doc="tracking window half-width (columns) "
                               "around the EKF's predicted bearing (localisation's window, "
                               "[localisation] search_cols, adds the estimate's spread)")
    window_rows: int = setting(6, ge=1, le=32, doc="tracking window half-height (rows)")
    initial_depth_m: float = setting(2.5, gt=0.0, le=50.0, doc="EKF prior depth (§4.6)")
    reference_bearing_sigma_deg: float = setting(
        0.1, gt=0.0, le=10.0, doc="EKF prior on a landmark's reference bearing: measured in "
        "the reference panorama at a known pose, to a fraction of a column")
    heading_noise_per_m: float = setting(0.02, ge=0.0, le=1.0,
                                         doc="EKF odometry heading noise gained per metre")
    observation_variance_scale: float = setting(
        0.015, gt=0.0, le=100.0, doc="EKF: the thesis's NCC noise model σ² = ((1 − c)π + "
        "π/180)² (§4.6.2) times this (σ 1.2° at NCC 0.95; tracking errors are correlated "
        "over frames, so a few times the ~0.6° per-frame error)")
    zoom_noise_rad: float = setting(
        0.7, ge=0.0, le=10.0, doc="EKF: bearing noise std (rad) per unit of ln zoom, added "
        "to the NCC term: a template on a landmark that appears larger or smaller than when "
        "cut slides, the same way every frame. With the scale above it keeps the 2-sigma "
        "coverage honest in `placecell-eval depth` (markers 0.7 m away and a 7 x 10 m room)")
    ekf_max_zoom: float = setting(
        1.5, ge=1.0, le=100.0, doc="EKF: bearings are used only while the landmark appears "
        "at most this much larger or smaller than in the reference (template matching is not "
        "scale invariant: beyond it a track slides off; the thesis shortened its cross toward "
        "the corridor walls, §4.6.4); zoom_noise_rad lets it exceed localisation's max_zoom")


@dataclass(frozen=True)
class OdometryNoiseSettings:
    """How uncertain the base's odometry is (docs/design.md §6: a transition's covariance grows with
    the distance driven between the two reference poses). Random parts grow with the square
    root of the distance; the unknown systematic parts (a scale error and a heading drift
    per metre) are carried as states, so their effect grows with the distance itself."""

    translation_m_per_sqrt_m: float = setting(
        0.015, ge=0.0, le=1.0, doc="random position error per sqrt(metre) driven")
    heading_rad_per_sqrt_m: float = setting(
        0.005, ge=0.0, le=1.0, doc="random heading error per sqrt(metre) driven")
    scale_sigma: float = setting(
        0.01, ge=0.0, le=0.5, doc="std of the unknown fractional error of distances")
    heading_drift_sigma_rad_per_m: float = setting(
        0.025, ge=0.0, le=1.0, doc="std of the unknown heading drift per metre driven")
    max_gap_s: float = setting(
        1.0, gt=0.0, le=60.0, doc="odometry silent longer than this breaks the run: no "
        "transition from odometry across the gap")


@dataclass(frozen=True)
class MappingSettings:
    """Place learning in the running daemon (docs/design.md §6, §11)."""

    mode: Literal["mapping", "localisation"] = setting(
        "mapping", doc="mapping: places may be learned; localisation: the map is read-only")
    acquisition: AcquisitionSettings = setting(default_factory=lambda: AcquisitionSettings())
    learn_threads: int = setting(2, ge=1, le=64, doc="threads a learn's matching after the "
                                 "drive (backgrounds, look-alikes, their features) is spread "
                                 "over; 1: the learn's own thread alone (the same result)")


@dataclass(frozen=True)
class AcquisitionSettings:
    """When to learn a new place on the robot's own (design §6, thesis §7.1): the LRP of the
    most recent place, smoothed against distance travelled, has settled at its background."""

    enabled: bool = setting(True, doc="learn places on the robot's own in mapping mode")
    operator_quiet_s: float = setting(30.0, ge=0.0, le=3600.0, doc="no place is learned on "
                                      "the robot's own this long after an operator's command")
    retry_after_s: float = setting(10.0, ge=0.0, le=3600.0, doc="after a learn of its own "
                                   "that stored nothing, wait this long before the next")
    unmapped_after_frames: int = setting(30, ge=1, le=100_000, doc="relocalisation that has "
                                         "found no known place in this many frames...")
    unmapped_after_m: float = setting(0.3, ge=0.0, le=100.0, doc="...while the robot "
                                      "travelled this far: unmapped space; a place is learned "
                                      "there and starts a new segment (design §6)")
    sample_step_m: float = setting(0.05, gt=0.0, le=1.0, doc="the LRP is sampled every this "
                                   "far travelled (frames while stationary or only turning "
                                   "add nothing)")
    window_m: float = setting(0.5, gt=0.0, le=10.0, doc="moving-average window and slope "
                              "baseline, in metres travelled")
    slope_threshold: float = setting(0.01, gt=0.0, le=1.0, doc="background: the smoothed "
                                     "change of the smoothed LRP over window_m below this...")
    lrp_max: float = setting(0.85, ge=0.0, le=1.0, doc="...while the LRP is between "
                             "[localisation] background_lrp (below it counts as background "
                             "at once) and this")
    min_distance_m: float = setting(0.75, ge=0.0, le=100.0, doc="at least this far "
                                    "from the last place (by odometry, and travelled as far) "
                                    "and from any the map puts near the tracked estimate "
                                    "before a new one is learned")
    background_window_m: float = setting(3.0, gt=0.0, le=100.0, doc="after the decision, "
                                         "the place's background LRP is the median of its LRP "
                                         "over this far travelled no nearer to the place "
                                         "than the decision came (the level it settles at)")
    background_skip_m: float = setting(1.0, ge=0.0, le=100.0, doc="...counted from this far "
                                       "after the decision (nearer, the LRP has not settled)")
    coverage_margin: float = setting(0.08, ge=0.0, le=1.0, doc="learn the next place "
                                     "while the last one's LRP is still this far above the "
                                     "background it is estimated to settle at (0: the "
                                     "thesis's rule alone)")
    coverage_window_m: float = setting(0.15, gt=0.0, le=10.0, doc="...the LRP averaged "
                                       "over this far travelled (window_m's average lags "
                                       "half a window behind)")
    recognition_margin: float = setting(0.05, ge=0.0, le=1.0, doc="when the background is "
                                        "reached, a known place whose LRP is this far above "
                                        "its own background (and coverage_margin) is watched "
                                        "instead of learning a new one (back on a known path)")
    known_within_m: float = setting(3.0, gt=0.0, le=100.0, doc="...if, while tracking, "
                                    "the map's transitions put its reference within this "
                                    "of the estimate (2 sigma of the path's drift allowed; "
                                    "one no path reaches is not ruled out): a look-alike "
                                    "elsewhere in the map is not a path back")
    certain_lead: float = setting(0.15, ge=0.0, le=1.0, doc="...or wherever the map puts "
                                  "it, if it stands this far above its background: the "
                                  "robot is at it, whatever the map's drift says (offices 1 "
                                  "and 3: 0.083 at most in 45,618 reference views 2 m or "
                                  "more from the place)")
    revisit_candidates: int = setting(3, ge=0, le=100, doc="while a place is watched, the "
                                      "places whose signatures are most like the view are "
                                      "recognised every frame, this many; one standing "
                                      "certain_lead above its background and above the "
                                      "watched place is where the robot is: watched "
                                      "instead, and tracked in (0: not looked for)")
