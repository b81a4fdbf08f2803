"""Settings of local positioning and global localisation (``[localisation]``, design
§7-9, thesis §8.1-8.2, §9)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from kernel.settings import setting

SensorModelName = Literal["assumed", "estimated", "ellipsoid"]


@dataclass(frozen=True)
class LocalisationSettings:
    seed: int = setting(0, ge=0, doc="seed of the particle filter's random generator (a "
                        "replay through the daemon gives the same poses)")
    initial_place: int = setting(0, ge=0, doc="track from initial_pose in this place as "
                                 "soon as the daemon starts (0: wait for cmd/set_pose)")
    initial_pose: list[float] = setting([0.0, 0.0, 0.0], doc="x, y, yaw in initial_place")
    particles: int = setting(2000, ge=50, le=100_000, doc="particles (thesis: 2000)")
    sensor_model: SensorModelName = setting(
        "ellipsoid", doc="assumed | estimated | ellipsoid (§8.1.4; the third is the default)")
    initial_sigma_xy_m: float = setting(0.1, gt=0.0, le=5.0,
                                        doc="set_pose without sigma_xy: the spread around it")
    initial_sigma_yaw_rad: float = setting(0.1, gt=0.0, le=3.2,
                                           doc="set_pose without sigma_yaw")
    orientation_ncc: float = setting(0.85, ge=0.0, le=1.0, doc="landmarks matching at least "
                                     "this well set the initial orientation (§8.1.5, eq. 8.34)")
    translation_noise: float = setting(0.05, ge=0.0, le=1.0,
                                       doc="motion model: translation std per metre moved")
    rotation_noise: float = setting(0.05, ge=0.0, le=1.0,
                                    doc="motion model: rotation std per radian turned")
    heading_noise_per_m: float = setting(0.02, ge=0.0, le=1.0,
                                         doc="motion model: rotation std per metre moved")
    delay_sigma_s: float = setting(0.02, ge=0.0, le=1.0, doc="camera-odometry sensing delay "
                                   "std: the velocity times this is added as noise (§8.1.5)")
    diffusion_xy_m: float = setting(0.002, ge=0.0, le=0.5,
                                    doc="per-frame std added to every particle (x, y)")
    diffusion_yaw_rad: float = setting(0.002, ge=0.0, le=0.5,
                                       doc="per-frame std added to every particle (yaw)")
    bearing_sigma_deg: float = setting(0.3, gt=0.0, le=20.0, doc="std of a tracked bearing "
                                       "at NCC 1 (the current observation; 0.06-0.36° "
                                       "measured, docs/design.md §7)")
    assumed_depth_m: float = setting(2.5, gt=0.0, le=50.0,
                                     doc="assumed-depth model: every landmark this far")
    assumed_depth_sigma_m: float = setting(1.5, gt=0.0, le=50.0,
                                           doc="assumed-depth model: its std")
    far_depth_m: float = setting(30.0, gt=1.0, le=1000.0, doc="a landmark without a finite "
                                 "depth estimate stands this far, as far uncertain")
    innovation_gate: float = setting(3.0, ge=0.0, le=100.0, doc="while tracking, a "
                                     "landmark found more than this many standard "
                                     "deviations from where the predicted pose expects "
                                     "it is left out for the frame (0: off)")
    gate_sigma: float = setting(3.0, gt=0.0, le=20.0, doc="ellipsoid model: the ellipse "
                                "holds this many standard deviations; a ray missing it "
                                "scores 0 (eq. 8.33)")
    outlier_floor: float = setting(0.02, gt=0.0, lt=1.0, doc="robust combination: each "
                                   "landmark's likelihood is floor + (1 - floor) p, so one "
                                   "mis-associated landmark cannot veto a particle")
    min_ncc: float = setting(0.6, ge=-1.0, lt=1.0, doc="a tracked landmark weighs "
                             "(NCC - min_ncc) / (1 - min_ncc); below it, nothing (eq. 8.10)")
    max_zoom: float = setting(1.35, ge=1.0, le=100.0, doc="landmarks appearing more than "
                              "this much larger or smaller than in the reference are not "
                              "used (a template matched at another scale slides)")
    search_cols: int = setting(12, ge=2, le=180, doc="tracking window half-width (columns) "
                               "beyond the estimate's own uncertainty")
    search_rows: int = setting(6, ge=1, le=32, doc="tracking window half-height (rows)")
    recognise_every: int = setting(5, ge=1, le=1000, doc="recognise the current place's "
                                   "neighbours every n-th frame (§8.2)")
    switch_margin: float = setting(0.02, ge=0.0, le=1.0, doc="a neighbour takes over when "
                                   "its LRP minus background leads the current place's by "
                                   "this (§8.2)")
    handover_m: float = setting(0.25, ge=0.0, le=10.0, doc="a neighbour whose reference "
                                "the estimate is this much nearer than the current "
                                "place's...")
    handover_ratio: float = setting(0.5, gt=0.0, le=1.0, doc="...and at most this "
                                    "fraction of the current place's distance takes "
                                    "over...")
    handover_tolerance: float = setting(0.1, ge=0.0, le=1.0, doc="...if its LRP minus "
                                        "background is at most this below the current "
                                        "place's")
    others_per_check: int = setting(4, ge=0, le=1000, doc="places beyond the neighbours "
                                    "tried per recognition, in turn (a place with no "
                                    "transition from here closes a cycle, §7.1.3)")
    cycle_margin: float = setting(0.08, ge=0.0, le=1.0, doc="a place with no transition "
                                  "from here must lead by this, on cycle_checks checks "
                                  "in a row, to be switched to")
    cycle_min_lead: float = setting(0.15, ge=0.0, le=1.0, doc="...and stand this far "
                                    "above its own background (recognised, not merely "
                                    "less unlike than the current place)...")
    cycle_near_m: float = setting(1.0, ge=0.0, le=10.0, doc="a place the transitions round "
                                  "a loop put this near (and no farther than the current "
                                  "place's reference) closes the cycle as soon as it is "
                                  "recognised above the current place and its neighbours")
    cycle_checks: int = setting(3, ge=1, le=100, doc="see cycle_margin")
    cycle_within_m: float = setting(3.0, ge=0.0, le=1000.0, doc="a place with no "
                                    "transition from here that the transitions put "
                                    "farther than this from the estimate (2 sigma of the "
                                    "path's drift allowed) is a look-alike: never switched "
                                    "to by its lead (office 5 handed a robot tracked 0.01 m "
                                    "off over to a place 9 m away by the map); one no path "
                                    "reaches is not ruled out; 0: no limit")
    reliable_sigma_m: float = setting(0.05, gt=0.0, le=5.0, doc="an estimate is reliable "
                                      "when its xy std is below this...")
    reliable_confidence: float = setting(0.5, ge=0.0, le=1.0,
                                         doc="...and its confidence above this")
    reliable_frames: int = setting(10, ge=1, le=1000, doc="...for this many frames in a row "
                                   "(then a cycle's transition is measured, §7.1.3)")
    recovery_sigma_m: float = setting(1.0, gt=0.0, le=10.0, doc="a place taken over without "
                                      "a transition: particles over this std around its "
                                      "reference (§9.3.2)")
    background_lrp: float = setting(0.7, ge=0.0, le=1.0,
                                    doc="a place's background LRP until it is measured")
    loss_output: float = setting(0.15, ge=0.0, le=1.0, doc="a frame whose raw sensor-model "
                                 "output at the estimate over all the place's landmarks "
                                 "(seen or not; 0.35-0.85 while tracking, 0.01-0.07 "
                                 "kidnapped) is below this counts towards a loss "
                                 "(§9.3.1)...")
    loss_frames: int = setting(5, ge=1, le=1000, doc="...and this many in a row are one")
    doubt_output: float = setting(0.05, ge=0.0, le=1.0, doc="a frame whose output over "
                                  "the usable landmarks is below this (or whose confidence "
                                  "is 0) is not published tracking: the view contradicts "
                                  "the estimate (kidnapped 0.000-0.013, tracking 0.11 and "
                                  "up on office 1's endurance run); state lost until the "
                                  "view agrees again or the loss is declared; a loss whose "
                                  "low frames never fell below it only faded (the robot "
                                  "drove out of the place's range): no kidnap (design §6)")
    blind_m: float = setting(2.0, ge=0.0, le=1000.0, doc="odometry travel with no "
                             "evidence (fewer than evidence_landmarks usable from the "
                             "estimate: odometry alone) that is a loss too; 0: never")
    bridge_max_m: float = setting(6.0, ge=0.0, le=100.0, doc="after a loss out of the "
                                  "place's view (see bridge_from_m), a relocalisation into a "
                                  "place the map does not join to the last one tracked, "
                                  "within this odometry travel of the last reliable "
                                  "estimate, measures the transition between them (segments "
                                  "joined, design §6); 0: never")
    bridge_from_m: float = setting(0.5, ge=0.0, le=100.0, doc="a loss nearer than this to "
                                   "the place's reference, where the place should be "
                                   "recognised, is a contradiction (carried off?): no "
                                   "transition is measured from before it")
    recovery_local_sigma_m: float = setting(0.2, gt=0.0, le=5.0, doc="recovery step 1: "
                                            "particles redistributed this far around the "
                                            "estimate (§9.3.2)")
    recovered_output: float = setting(0.3, ge=0.0, le=1.0, doc="a recovered or "
                                      "relocalised estimate must also reach this raw "
                                      "output (not just be sure of itself: a wrong mode "
                                      "can be)")
    evidence_landmarks: int = setting(8, ge=1, le=1000, doc="loss and recovery are "
                                      "judged only where at least this many of the "
                                      "place's landmarks are usable from the estimate")
    recovery_frames: int = setting(3, ge=1, le=1000, doc="frames each recovery step is "
                                   "given to become reliable before the next is tried")
    confirm_frames: int = setting(15, ge=1, le=10_000, doc="a place chosen by global "
                                  "relocalisation must give a reliable estimate within "
                                  "this many frames, or the search goes on without it")
    search_places_per_frame: int = setting(25, ge=1, le=100_000, doc="places recognised "
                                           "per frame while searching (a frame's budget; "
                                           "the rest on later frames, §9.4.2)")
    search_min_lead: float = setting(0.03, ge=-1.0, le=1.0, doc="global relocalisation "
                                     "picks the most likely place once every place has "
                                     "been recognised and its LRP minus background is at "
                                     "least this (§9.2)")
    cue_margin: float = setting(0.07, ge=0.0, le=2.0, doc="the active set: places whose "
                                "signature similarity is within this of the best "
                                "(design §9: 0.05 missed the true place on 2 % of "
                                "office 3's frames, 0.1 searched 8 % of a thousand "
                                "places; thesis §9.4.1's B for local space)")
    local_space: bool = setting(True, doc="track local space (design §4): the floor "
                                "learned from the first colour frame, a floor grid fed "
                                "every frame, and each place learned given its profile")
    local_space_margin: float = setting(1.0, ge=0.0, le=1.0, doc="the active set keeps "
                                        "only places whose local space profile matches "
                                        "within this of the best (thesis §9.4.1's B, "
                                        "0.075); 1, the default, keeps every place: on "
                                        "office 1 it cost inclusion (design §9)")
    local_space_every: int = setting(5, ge=1, le=1000, doc="while tracking, the floor "
                                     "grid is fed every this many frames (every frame "
                                     "while searching, confirming or recovering)")
    search_margin: float = setting(0.05, ge=0.0, le=1.0, doc="lost: a place leading the "
                                   "current one by this goes straight to global "
                                   "relocalisation (the robot was carried off)")
    led_frames: int = setting(3, ge=0, le=1000, doc="tracking: a place of the background "
                              "search leading the current one by search_margin this "
                              "many frames in a row is a loss at once, the robot "
                              "carried off or tracked in the wrong place (design §9; "
                              "0: only the sensor output declares a loss)")
    recovered_margin: float = setting(0.0, ge=-1.0, le=1.0, doc="recovery steps 1-2: a "
                                      "pose found again in the current place stands "
                                      "only while no place of the search leads it by "
                                      "more than this; else that place is tried "
                                      "(design §9)")
    lookalike_margin: float = setting(0.1, ge=0.0, le=1.0, doc="a place recognised in a "
                                      "new place's views within this of the new place's "
                                      "own lead is its look-alike: the pair's "
                                      "disambiguating features are found (design §5)")
    lookalike_min_distance_m: float = setting(
        1.6, ge=0.0, le=100.0, doc="places nearer than this through the map's transitions "
        "are neighbours, not look-alikes")
    max_lookalikes: int = setting(8, ge=0, le=1000, doc="features are found for at most "
                                  "this many look-alikes of a new place, the closest")
    lookalike_candidates: int = setting(
        50, ge=1, le=100000, doc="a new place's look-alikes are sought among this many "
        "places, those whose signatures are most like its views (design §5): a learn's "
        "work does not grow with the map")
    disambiguation: bool = setting(True, doc="tell look-alike places apart by their "
                                   "features (design §5); false: the lower levels alone")
    ambiguity_margin: float = setting(0.1, ge=0.0, le=1.0, doc="the search's top two "
                                      "within this of each other are ambiguous (§9.5)")
    ambiguity_frames: int = setting(3, ge=1, le=100, doc="ambiguous this many frames in a "
                                    "row: the pair's features decide (0 features: the "
                                    "lower levels' best)")
    disambiguation_min_vote: float = setting(0.07, ge=0.0, le=1.0, doc="the features "
                                             "overrule the lower levels' pick only when "
                                             "their place's vote leads its by this")
    disambiguation_min_evidence: float = setting(
        0.07, ge=0.0, le=1.0, doc="the features decide only when the winner's are seen "
        "(its vote above 0) and its vote leads the next place's by this; else the "
        "decision waits for a clearer view...")
    disambiguation_max_wait_frames: int = setting(
        20, ge=0, le=1000, doc="...for at most this many frames, then keeps the lower "
        "levels' pick")

    def __post_init__(self) -> None:
        if len(self.initial_pose) != 3:
            raise ValueError(f"localisation.initial_pose is [x, y, yaw], got "
                             f"{self.initial_pose}")
