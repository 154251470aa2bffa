//! Accuracy targets, met or not (issue 55). A test states its target through [`check`]: a met
//! target is asserted as it is; a target the shipped code misses is listed in [`UNMET`] with the
//! value measured, and the test holds that value as a ratchet (it fails if the code gets worse,
//! and fails too once the target is met, so the entry is removed rather than left stale).
//! `docs/known-issues.md` shows [`UNMET`] as a table between two markers; `tests/cpu.rs`
//! (`known_issues_lists_every_unmet_target`) fails when the two differ.

/// Which way a quantity improves.
#[derive(Clone, Copy, PartialEq, Debug)]
pub enum Better {
    Lower,
    Higher,
}

/// A target the shipped defaults miss, held as a ratchet.
pub struct Unmet {
    /// The key the test passes to [`check`].
    pub id: &'static str,
    /// The test that holds it: `file test_name`.
    pub test: &'static str,
    /// What is measured, in which configuration.
    pub quantity: &'static str,
    pub better: Better,
    /// The issue's target.
    pub target: f64,
    /// What the test asserts today: the measured value and a margin for run-to-run noise.
    pub ratchet: f64,
    /// Measured by the test (its printed line), with the date.
    pub measured: f64,
    pub date: &'static str,
    /// The issue that states the target.
    pub issue: u32,
}

/// Every unmet target. Keep `docs/known-issues.md` in step: `GILAB_BLESS=1 cargo test --release
/// --test cpu known_issues` rewrites its table.
pub const UNMET: &[Unmet] = &[
    Unmet {
        id: "restir-spatial-reuse-single-frame",
        test: "`tests/restir.rs` `reuse_lowers_single_frame_error`",
        quantity: "ReSTIR DI's frame-16 relMSE with spatial reuse alone (3 neighbours, radius 4) \
               over no reuse, many-lights 64², seed 1, against the reference's direct light. Since \
               the balance-heuristic reuse (2026-11-29) seed 1 reads 0.873 (1/Z read 0.850, at the \
               bound); over seeds 1-4 the two weightings gain the same (mean 0.763 against 0.760, \
               scratch run): this seed is at the test's noise",
        better: Better::Lower,
        target: 0.85,
        ratchet: 0.88,
        measured: 0.8730,
        date: "2026-11-29",
        issue: 55,
    },
    Unmet {
        id: "surfels-glossy-metal-energy",
        test: "`tests/reflections.rs` `surfels_reflect_the_room_in_glossy_metal`",
        quantity:
            "\\|energy / reference − 1\\| of the surfels at their defaults, metal Cornell box at \
               roughness 0.3, 64², 12 frames' warm-up then 24 accumulated (the Lambert box alone \
               reads 0.875: the surfels cover a 64² image slowly)",
        better: Better::Lower,
        target: 0.10,
        ratchet: 0.155,
        measured: 0.14853,
        date: "2026-11-28",
        issue: 55,
    },
    Unmet {
        id: "moving-frame-energy-surfels",
        test: "`tests/gpu.rs` `every_technique_plays_the_moving_scene`",
        quantity:
            "\\|energy / posed reference − 1\\| of the surfels' frame 8 of the `moving` scene \
               played at 12× from a cold start (32², seed 5): 8 frames spawn too few surfels at 32²",
        better: Better::Lower,
        target: 0.20,
        ratchet: 0.33,
        measured: 0.3184,
        date: "2026-11-28",
        issue: 55,
    },
    Unmet {
        id: "lumen-reassignment-vs-cdf-courtyard",
        test: "`tests/lumen.rs` `probe_ray_reassignment_keeps_the_energy`",
        quantity:
            "Lumen's probe ray reassignment: its one-frame 8×8 block relMSE over the CDF draw's \
               on courtyard (64², BVH, probe filters off; issue 38 wants it below 1). With the \
               engine seed set to 2 and 3 in a scratch copy it read 0.898 and 0.925 (mean over \
               seeds 1-3 0.945, 2026-11-30): this seed is at the test's noise",
        better: Better::Lower,
        target: 1.0,
        ratchet: 1.02,
        measured: 1.0127,
        date: "2026-11-28",
        issue: 55,
    },
];

fn meets(better: Better, value: f64, bound: f64) -> bool {
    match better {
        Better::Lower => value <= bound,
        Better::Higher => value >= bound,
    }
}

/// Checks `value` (what `what` says) against `target`. Met targets must stay met; an unmet one
/// (listed in [`UNMET`] under `id`) must stay within its ratchet and must not be met silently.
pub fn check(id: &str, better: Better, target: f64, value: f64, what: &str) {
    assert!(value.is_finite(), "{id}: {what} is {value}");
    match UNMET.iter().find(|u| u.id == id) {
        None => {
            let met = if meets(better, value, target) {
                "met"
            } else {
                "MISSED"
            };
            eprintln!("target {id}: {what} = {value:.5}, target {target} ({met})");
            assert!(
                meets(better, value, target),
                "{id}: {what} = {value} misses its target {target} ({better:?} is better)"
            );
        }
        Some(u) => {
            assert_eq!(u.better, better, "{id}: direction differs from UNMET");
            assert_eq!(u.target, target, "{id}: target differs from UNMET");
            eprintln!(
                "target {id}: {what} = {value:.5}, target {target} UNMET (ratchet {}, measured {} on {})",
                u.ratchet, u.measured, u.date
            );
            assert!(
                !meets(better, value, target),
                "{id}: {what} = {value} now meets its target {target}: remove it from UNMET \
                 (tests/common/targets.rs) and docs/known-issues.md"
            );
            assert!(
                meets(better, value, u.ratchet),
                "{id}: {what} = {value} is worse than its ratchet {} (measured {} on {})",
                u.ratchet,
                u.measured,
                u.date
            );
        }
    }
}

/// The Markdown table `docs/known-issues.md` shows.
pub fn markdown_table() -> String {
    let mut s = String::from(
        "| id | test | quantity | better | target | measured | ratchet (asserted) | measured on |\n\
         | --- | --- | --- | --- | ---: | ---: | ---: | --- |\n",
    );
    for u in UNMET {
        s += &format!(
            "| `{}` (issue {}) | {} | {} | {} | {} | {} | {} | {} |\n",
            u.id,
            u.issue,
            u.test,
            u.quantity,
            match u.better {
                Better::Lower => "lower",
                Better::Higher => "higher",
            },
            u.target,
            u.measured,
            u.ratchet,
            u.date
        );
    }
    s
}
