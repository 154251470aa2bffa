//! The global distance field's clipmaps on the CPU: where each level sits around the camera,
//! which levels are built (rule 3), and what changed since the last frame (scrolling, scene
//! edits), so the GPU passes rebuild only those bricks.

use super::params::LevelGpu;
use glam::{IVec3, Vec3};

pub const MAX_LEVELS: usize = 6;
pub const BRICK: u32 = 8;
/// Level 0 spans this fraction of the scene's diagonal; each level doubles it (4 levels reach two
/// diagonals around the camera: the whole scene from a camera well outside it).
pub const LEVEL0_FRACTION: f32 = 0.5;
/// Scene edits beyond this many boxes rebuild whole levels instead.
pub const MAX_DIRTY_BOXES: usize = 64;

/// Where the clipmaps are and what the GPU holds.
#[derive(Clone, Debug)]
pub struct Clipmaps {
    pub resolution: u32,
    pub levels: u32,
    pub voxel0: f32,
    pub bounds: (Vec3, Vec3),
    /// Levels built this frame (the first that holds the whole scene ends the list).
    pub built: u32,
    pub brick_origins: [IVec3; MAX_LEVELS],
    /// Whether the GPU holds level l at `brick_origins[l]`.
    pub valid: [bool; MAX_LEVELS],
    /// Scene edits not yet applied: world boxes.
    pub dirty: Vec<(Vec3, Vec3)>,
}

/// One frame's update plan.
#[derive(Clone, Debug, Default)]
pub struct SdfPlan {
    pub levels: [LevelGpu; MAX_LEVELS],
    pub built: u32,
    pub any_update: bool,
    pub dirty: Vec<[f32; 4]>,
}

impl Clipmaps {
    pub fn new(resolution: u32, levels: u32, bounds: (Vec3, Vec3)) -> Clipmaps {
        let diag = (bounds.1 - bounds.0).length().max(1e-3);
        Clipmaps {
            resolution,
            levels: levels.min(MAX_LEVELS as u32),
            voxel0: LEVEL0_FRACTION * diag / resolution as f32,
            bounds,
            built: 0,
            brick_origins: [IVec3::ZERO; MAX_LEVELS],
            valid: [false; MAX_LEVELS],
            dirty: Vec::new(),
        }
    }

    pub fn voxel(&self, level: u32) -> f32 {
        self.voxel0 * (1u32 << level) as f32
    }

    pub fn bricks_per_axis(&self) -> u32 {
        self.resolution / BRICK
    }

    /// Minimum brick coordinate of level l centred on `camera` (snapped to whole bricks, so a
    /// move shifts the level by whole slabs).
    pub fn brick_origin(&self, level: u32, camera: Vec3) -> IVec3 {
        let brick = BRICK as f32 * self.voxel(level);
        let centre = (camera / brick).floor().as_ivec3();
        centre - IVec3::splat(self.bricks_per_axis() as i32 / 2)
    }

    pub fn level_box(&self, level: u32, origin: IVec3) -> (Vec3, Vec3) {
        let brick = BRICK as f32 * self.voxel(level);
        let lo = origin.as_vec3() * brick;
        (
            lo,
            lo + Vec3::splat(self.resolution as f32 * self.voxel(level)),
        )
    }

    /// Levels to build for this camera: up to and including the first whose box holds the
    /// whole scene (larger ones would only hold empty space around it).
    pub fn levels_needed(&self, camera: Vec3) -> u32 {
        for l in 0..self.levels {
            let (lo, hi) = self.level_box(l, self.brick_origin(l, camera));
            let margin = Vec3::splat(self.voxel(l));
            if (self.bounds.0 - margin).cmpge(lo).all() && (self.bounds.1 + margin).cmple(hi).all()
            {
                return l + 1;
            }
        }
        self.levels
    }

    /// Forget everything on the GPU: every level is rebuilt whole.
    pub fn invalidate(&mut self) {
        self.valid = [false; MAX_LEVELS];
        self.dirty.clear();
    }

    /// This frame's plan for `camera`; marks the plan as applied.
    pub fn plan(&mut self, camera: Vec3) -> SdfPlan {
        let built = self.levels_needed(camera);
        let mut plan = SdfPlan {
            built,
            ..Default::default()
        };
        let edits = !self.dirty.is_empty();
        if self.dirty.len() > MAX_DIRTY_BOXES {
            self.invalidate();
        }
        for (lo, hi) in self.dirty.drain(..) {
            plan.dirty.push(lo.extend(0.0).to_array());
            plan.dirty.push(hi.extend(0.0).to_array());
        }
        for l in 0..MAX_LEVELS as u32 {
            let li = l as usize;
            if l >= built {
                self.valid[li] = false;
                continue;
            }
            let origin = self.brick_origin(l, camera);
            let whole = !self.valid[li];
            let scrolled = origin != self.brick_origins[li];
            let update = whole || scrolled || edits;
            // Edits alone: coarse cells far from every edited box keep their distance.
            let edits_only = edits && !whole && !scrolled;
            let (lo, _) = self.level_box(l, origin);
            plan.levels[li] = LevelGpu {
                origin: [lo.x, lo.y, lo.z, self.voxel(l)],
                brick_origin: [origin.x, origin.y, origin.z, 1],
                update: [update as u32, whole as u32, edits_only as u32, 0],
            };
            plan.any_update |= update;
            self.brick_origins[li] = origin;
            self.valid[li] = true;
        }
        self.built = built;
        plan
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scrolling_updates_only_moved_levels_and_keeps_origins_whole_bricks() {
        let mut c = Clipmaps::new(64, 4, (Vec3::splat(-1.0), Vec3::splat(1.0)));
        let first = c.plan(Vec3::ZERO);
        assert!(first.any_update);
        assert!(first.levels[..first.built as usize]
            .iter()
            .all(|l| l.update == [1, 1, 0, 0]));
        let same = c.plan(Vec3::ZERO);
        assert!(!same.any_update, "a still camera rebuilds nothing");
        // A move of one level-0 brick scrolls level 0 only (coarser bricks are larger).
        let step = BRICK as f32 * c.voxel(0);
        let moved = c.plan(Vec3::new(step * 1.01, 0.0, 0.0));
        assert_eq!(moved.levels[0].update, [1, 0, 0, 0]);
        assert_eq!(moved.levels[1].update[0], 0);
    }

    #[test]
    fn levels_past_the_one_holding_the_scene_are_not_built() {
        let c = Clipmaps::new(64, 6, (Vec3::splat(-1.0), Vec3::splat(1.0)));
        let n = c.levels_needed(Vec3::ZERO);
        assert!(n < 6, "level {n}");
        let (lo, hi) = c.level_box(n - 1, c.brick_origin(n - 1, Vec3::ZERO));
        assert!(lo.cmple(Vec3::splat(-1.0)).all() && hi.cmpge(Vec3::splat(1.0)).all());
    }
}
