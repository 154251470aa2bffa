//! Surface cache cards on the CPU: objects (connected triangle groups), axis-aligned card
//! placement per object, and the atlas layout in 128x128 physical pages.
//!
//! The seed voxelises each mesh into axis-aligned surfels and clusters them into up to N cards.
//! Scenes here are triangle soups, so an object is a connected component (triangles sharing a
//! welded vertex), and clustering works per side: the triangles that face a side are sorted by
//! depth along its axis and split into layers wherever a gap opens (a concave object, such as a
//! room with a step, gets one card per layer). Each layer is a card; an object keeps its
//! `MAX_CARDS_PER_OBJECT` largest by projected area.

use crate::scene::bvh::Bvh;
use crate::scene::gpu_scene::SceneData;
use anyhow::{bail, Result};
use glam::Vec3;
use std::collections::HashMap;

/// Physical page side in texels (the seed's 128x128 pages in a 4k atlas).
pub const PAGE: u32 = 128;
/// Card sides are multiples of the direct-lighting tile (8 texels), so tiles never straddle cards.
pub const CARD_GRANULE: u32 = 8;
/// Six sides plus extra layers for concave objects.
pub const MAX_CARDS_PER_OBJECT: usize = 16;
/// A triangle of no instance (`triangle_instances`).
pub const NO_INSTANCE: u32 = u32::MAX;
/// Share of the atlas the first layout attempt aims to fill.
const TARGET_FILL: f32 = 0.4;

/// `Card` of shaders/parts/surface_cache/card.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuCard {
    /// xyz: box minimum, w: side (bits): 0 +x, 1 -x, 2 +y, 3 -y, 4 +z, 5 -z.
    pub box_min: [f32; 4],
    /// xyz: box maximum, w: object (bits).
    pub box_max: [f32; 4],
    /// Atlas rectangle x, y, width, height.
    pub rect: [u32; 4],
    /// First capture index, index count, page, unused.
    pub draw: [u32; 4],
}

impl GpuCard {
    pub fn side(&self) -> u32 {
        self.box_min[3].to_bits()
    }
    pub fn object(&self) -> u32 {
        self.box_max[3].to_bits()
    }
    pub fn centre(&self) -> Vec3 {
        (Vec3::from_slice(&self.box_min[..3]) + Vec3::from_slice(&self.box_max[..3])) * 0.5
    }
    pub fn texels(&self) -> u32 {
        self.rect[2] * self.rect[3]
    }
}

/// Cards, the object tables the shaders need and the capture index buffer.
#[derive(Clone, Debug, Default)]
pub struct CardSet {
    pub cards: Vec<GpuCard>,
    /// Per object: first card, card count (cards are grouped by object).
    pub object_cards: Vec<[u32; 2]>,
    /// Per scene triangle: its object.
    pub tri_object: Vec<u32>,
    /// Capture vertex indices (into the scene's raster vertex buffer, BVH order), by object.
    pub indices: Vec<u32>,
    /// World size of a texel before per-card clamping.
    pub texel_size: f32,
    pub pages_used: u32,
    /// Per object: its instance (`NO_INSTANCE`: the rest of the scene).
    pub object_instance: Vec<u32>,
    /// The padding its layers were built with (a re-placed card keeps it).
    pub pad: f32,
}

impl CardSet {
    pub fn object_count(&self) -> usize {
        self.object_cards.len()
    }
    /// 8x8 direct-lighting tiles: (tile x | tile y << 16, card).
    pub fn tiles(&self, size: u32) -> Vec<[u32; 2]> {
        let mut out = Vec::new();
        for (i, c) in self.cards.iter().enumerate() {
            for ty in 0..c.rect[3] / size {
                for tx in 0..c.rect[2] / size {
                    let x = c.rect[0] / size + tx;
                    let y = c.rect[1] / size + ty;
                    out.push([x | (y << 16), i as u32]);
                }
            }
        }
        out
    }
}

/// Double-sidedness per scene triangle, from the BVH-ordered attributes.
fn two_sided(data: &SceneData) -> Vec<bool> {
    let mut two_sided = vec![false; data.tris.len()];
    for (bvh_index, &orig) in data.bvh.order.iter().enumerate() {
        let m = data.tri_attr[bvh_index].material() as usize;
        two_sided[orig as usize] = data.materials.get(m).is_some_and(|m| m.emissive[3] > 0.5);
    }
    two_sided
}

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        parent[i as usize] = parent[parent[i as usize] as usize];
        i = parent[i as usize];
    }
    i
}

/// Per scene triangle: the instance it belongs to (`NO_INSTANCE`: the rest of the scene), from
/// the two-level BVH's top level.
pub fn triangle_instances(bvh: &Bvh, n: usize) -> Vec<u32> {
    let mut out = vec![NO_INSTANCE; n];
    let Some(top) = &bvh.top else {
        return out;
    };
    for (e, entry) in top.entries.iter().enumerate() {
        let Some(j) = entry.instance else {
            continue;
        };
        let end = top
            .entries
            .get(e + 1)
            .map_or(bvh.order.len(), |x| x.tri_offset as usize)
            .min(bvh.order.len());
        for &orig in &bvh.order[(entry.tri_offset as usize).min(end)..end] {
            if let Some(t) = out.get_mut(orig as usize) {
                *t = j as u32;
            }
        }
    }
    out
}

/// Object id per triangle: connected components over vertices welded at 1e-5 of the scene's
/// size, never across instances (`instance` per triangle), so an object moves with one instance.
pub fn objects(tris: &[[Vec3; 3]], instance: &[u32]) -> (Vec<u32>, usize) {
    let mut lo = Vec3::splat(f32::MAX);
    let mut hi = Vec3::splat(f32::MIN);
    for t in tris {
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let eps = ((hi - lo).length() * 1e-5).max(1e-9);
    let n = tris.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    let mut first: HashMap<[i64; 4], u32> = HashMap::new();
    for (t, tri) in tris.iter().enumerate() {
        let inst = instance.get(t).copied().unwrap_or(NO_INSTANCE) as i64;
        for p in tri {
            let key = [
                (p.x / eps).round() as i64,
                (p.y / eps).round() as i64,
                (p.z / eps).round() as i64,
                inst,
            ];
            let other = *first.entry(key).or_insert(t as u32);
            let (a, b) = (find(&mut parent, t as u32), find(&mut parent, other));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    let mut ids = HashMap::new();
    let mut out = Vec::with_capacity(n);
    for t in 0..n as u32 {
        let r = find(&mut parent, t);
        let next = ids.len() as u32;
        out.push(*ids.entry(r).or_insert(next));
    }
    (out, ids.len())
}

/// A card before it has a place in the atlas.
#[derive(Clone, Debug)]
struct Layer {
    side: u32,
    lo: Vec3,
    hi: Vec3,
    area: f32,
}

fn side_dir(side: u32) -> Vec3 {
    let mut d = Vec3::ZERO;
    d[(side / 2) as usize] = if side & 1 == 1 { -1.0 } else { 1.0 };
    d
}

/// The card layers of one object's triangles.
fn object_layers(tris: &[[Vec3; 3]], double_sided: &[bool], pad: f32) -> Vec<Layer> {
    let mut lo = Vec3::splat(f32::MAX);
    let mut hi = Vec3::splat(f32::MIN);
    for t in tris {
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let gap = ((hi - lo).length() * 0.02).max(4.0 * pad);
    let mut layers = Vec::new();
    for side in 0..6u32 {
        let dir = side_dir(side);
        let axis = (side / 2) as usize;
        // (front depth, back depth, box, projected area): depth grows away from the card.
        let mut facing: Vec<(f32, f32, Vec3, Vec3, f32)> = Vec::new();
        for (t, &two) in tris.iter().zip(double_sided) {
            let n = (t[1] - t[0]).cross(t[2] - t[0]);
            let area = 0.5 * n.length();
            if area <= 0.0 {
                continue;
            }
            let c = n.normalize().dot(dir);
            if !(c > 0.1 || (two && c < -0.1)) {
                continue;
            }
            let tlo = t[0].min(t[1]).min(t[2]);
            let thi = t[0].max(t[1]).max(t[2]);
            let (front, back) = if side & 1 == 1 {
                (tlo[axis], thi[axis])
            } else {
                (-thi[axis], -tlo[axis])
            };
            facing.push((front, back, tlo, thi, area * c.abs()));
        }
        facing.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut current: Option<(f32, Layer)> = None;
        for (front, back, tlo, thi, area) in facing {
            match &mut current {
                Some((end, layer)) if front <= *end + gap => {
                    *end = end.max(back);
                    layer.lo = layer.lo.min(tlo);
                    layer.hi = layer.hi.max(thi);
                    layer.area += area;
                }
                _ => {
                    if let Some((_, l)) = current.take() {
                        layers.push(l);
                    }
                    current = Some((
                        back,
                        Layer {
                            side,
                            lo: tlo,
                            hi: thi,
                            area,
                        },
                    ));
                }
            }
        }
        if let Some((_, l)) = current {
            layers.push(l);
        }
    }
    layers.sort_by(|a, b| b.area.total_cmp(&a.area));
    layers.truncate(MAX_CARDS_PER_OBJECT);
    for l in &mut layers {
        l.lo -= Vec3::splat(pad);
        l.hi += Vec3::splat(pad);
    }
    layers
}

fn card_extent(side: u32, lo: Vec3, hi: Vec3) -> (f32, f32) {
    let a = (side / 2) as usize;
    let size = hi - lo;
    (size[(a + 1) % 3], size[(a + 2) % 3])
}

fn texels_for(extent: f32, texel: f32) -> u32 {
    let t = (extent / texel).ceil().max(1.0) as u32;
    t.div_ceil(CARD_GRANULE).clamp(1, PAGE / CARD_GRANULE) * CARD_GRANULE
}

/// Places cards in pages with a shelf packer; None when they do not fit.
fn pack(sizes: &[(u32, u32)], atlas: u32) -> Option<(Vec<[u32; 3]>, u32)> {
    let pages_per_side = atlas / PAGE;
    let pages = pages_per_side * pages_per_side;
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(sizes[i].1), std::cmp::Reverse(sizes[i].0)));
    let mut out = vec![[0u32; 3]; sizes.len()];
    let (mut page, mut x, mut y, mut shelf) = (0u32, 0u32, 0u32, 0u32);
    for i in order {
        let (w, h) = sizes[i];
        if x + w > PAGE {
            x = 0;
            y += shelf;
            shelf = 0;
        }
        if y + h > PAGE {
            page += 1;
            x = 0;
            y = 0;
            shelf = 0;
        }
        if page >= pages {
            return None;
        }
        let px = (page % pages_per_side) * PAGE;
        let py = (page / pages_per_side) * PAGE;
        out[i] = [px + x, py + y, page];
        x += w;
        shelf = shelf.max(h);
    }
    Some((out, page + 1))
}

/// Cards for every object of the scene, laid out in an atlas of `atlas` texels.
pub fn build(data: &SceneData, atlas: u32) -> Result<CardSet> {
    let tri_instance = triangle_instances(&data.bvh, data.tris.len());
    let (tri_object, object_count) = objects(&data.tris, &tri_instance);
    let mut object_instance = vec![NO_INSTANCE; object_count];
    for (t, &o) in tri_object.iter().enumerate() {
        object_instance[o as usize] = tri_instance[t];
    }
    let f = &data.features;
    let pad = (Vec3::from(f.bounds_max) - Vec3::from(f.bounds_min)).length() * 1e-3;
    let two_sided = two_sided(data);
    let mut per_object: Vec<Vec<[Vec3; 3]>> = vec![Vec::new(); object_count];
    let mut per_object_two: Vec<Vec<bool>> = vec![Vec::new(); object_count];
    for (t, tri) in data.tris.iter().enumerate() {
        let o = tri_object[t] as usize;
        per_object[o].push(*tri);
        per_object_two[o].push(two_sided[t]);
    }
    // Capture indices by object, in the raster vertex buffer's (BVH) order.
    let mut by_object: Vec<Vec<u32>> = vec![Vec::new(); object_count];
    for (bvh_index, &orig) in data.bvh.order.iter().enumerate() {
        let o = tri_object[orig as usize] as usize;
        let base = 3 * bvh_index as u32;
        by_object[o].extend([base, base + 1, base + 2]);
    }
    let mut indices = Vec::new();
    let mut ranges = Vec::with_capacity(object_count);
    for list in &by_object {
        ranges.push([indices.len() as u32, list.len() as u32]);
        indices.extend_from_slice(list);
    }
    let mut layers: Vec<(u32, Layer)> = Vec::new();
    for (o, tris) in per_object.iter().enumerate() {
        for l in object_layers(tris, &per_object_two[o], pad) {
            layers.push((o as u32, l));
        }
    }
    let area: f32 = layers
        .iter()
        .map(|(_, l)| {
            let (u, v) = card_extent(l.side, l.lo, l.hi);
            u * v
        })
        .sum();
    let mut texel = (area / (TARGET_FILL * (atlas as f32).powi(2)))
        .sqrt()
        .max(1e-9);
    for _ in 0..40 {
        let sizes: Vec<(u32, u32)> = layers
            .iter()
            .map(|(_, l)| {
                let (u, v) = card_extent(l.side, l.lo, l.hi);
                (texels_for(u, texel), texels_for(v, texel))
            })
            .collect();
        if let Some((places, pages_used)) = pack(&sizes, atlas) {
            let mut cards = Vec::with_capacity(layers.len());
            let mut object_cards = vec![[0u32, 0u32]; object_count];
            for (i, (o, l)) in layers.iter().enumerate() {
                if object_cards[*o as usize][1] == 0 {
                    object_cards[*o as usize][0] = cards.len() as u32;
                }
                object_cards[*o as usize][1] += 1;
                let r = ranges[*o as usize];
                cards.push(GpuCard {
                    box_min: [l.lo.x, l.lo.y, l.lo.z, f32::from_bits(l.side)],
                    box_max: [l.hi.x, l.hi.y, l.hi.z, f32::from_bits(*o)],
                    rect: [places[i][0], places[i][1], sizes[i].0, sizes[i].1],
                    draw: [r[0], r[1], places[i][2], 0],
                });
            }
            return Ok(CardSet {
                cards,
                object_cards,
                tri_object,
                indices,
                texel_size: texel,
                pages_used,
                object_instance,
                pad,
            });
        }
        texel *= 1.25;
    }
    bail!(
        "lumen: {} cards of {} objects do not fit a {atlas}^2 atlas even at the smallest card size; raise atlas_size",
        layers.len(),
        object_count
    )
}

impl CardSet {
    /// Re-places the cards of `moved` objects on their current triangles (the seed's cards follow
    /// their object): each object's layers are found again and take the boxes of its cards
    /// side by side, nearest layer first. Where they no longer match its cards side by side (a
    /// turning object can gain or lose a layer), its cards follow its box instead, the old box
    /// mapped onto the new one (`old`: the triangles before). Atlas rectangles, capture ranges and every other card
    /// stay, so the atlas keeps its texels. Returns the cards changed.
    pub fn replace_objects(
        &mut self,
        data: &SceneData,
        old: &[[Vec3; 3]],
        moved: &[u32],
    ) -> Vec<u32> {
        let two = two_sided(data);
        type Tris = (Vec<[Vec3; 3]>, Vec<bool>, Vec3, Vec3);
        let empty = (Vec::new(), Vec::new(), Vec3::ZERO, Vec3::ZERO);
        let mut per: Vec<Tris> = vec![empty; moved.len()];
        let mut old_box = vec![(Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)); moved.len()];
        let slot: HashMap<u32, usize> = moved.iter().enumerate().map(|(i, &o)| (o, i)).collect();
        for (t, tri) in data.tris.iter().enumerate() {
            if let Some(&i) = self.tri_object.get(t).and_then(|o| slot.get(o)) {
                per[i].0.push(*tri);
                per[i].1.push(two[t]);
                if let Some(p) = old.get(t) {
                    old_box[i].0 = old_box[i].0.min(p[0].min(p[1]).min(p[2]));
                    old_box[i].1 = old_box[i].1.max(p[0].max(p[1]).max(p[2]));
                }
            }
        }
        let mut updates = Vec::new();
        for ((&o, (tris, two, _, _)), (olo, ohi)) in moved.iter().zip(&per).zip(old_box) {
            let Some(&[first, count]) = self.object_cards.get(o as usize) else {
                continue;
            };
            let layers = object_layers(tris, two, self.pad);
            let matched = self.match_layers(first, count, &layers);
            if let Some(m) = matched {
                updates.extend(m);
                continue;
            }
            let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
            for t in tris {
                lo = lo.min(t[0].min(t[1]).min(t[2]));
                hi = hi.max(t[0].max(t[1]).max(t[2]));
            }
            // The old box mapped onto the new one, axis by axis (a turn or a scale changes it).
            let scale = (hi - lo) / (ohi - olo).max(Vec3::splat(1e-12));
            let map = |p: Vec3| lo + (p - olo) * scale;
            for c in first..first + count {
                let k = &self.cards[c as usize];
                updates.push((
                    c,
                    map(Vec3::from_slice(&k.box_min[..3])),
                    map(Vec3::from_slice(&k.box_max[..3])),
                ));
            }
        }
        let mut changed = Vec::with_capacity(updates.len());
        for (c, lo, hi) in updates {
            let card = &mut self.cards[c as usize];
            card.box_min = [lo.x, lo.y, lo.z, card.box_min[3]];
            card.box_max = [hi.x, hi.y, hi.z, card.box_max[3]];
            changed.push(c);
        }
        changed
    }

    /// An object's new layers against its cards `first..first + count`, side by side, nearest
    /// first: (card, box) each, or None where the counts differ.
    fn match_layers(
        &self,
        first: u32,
        count: u32,
        layers: &[Layer],
    ) -> Option<Vec<(u32, Vec3, Vec3)>> {
        if layers.len() != count as usize {
            return None;
        }
        let mut updates = Vec::new();
        {
            // Front depth along a side's view (nearest the card first).
            let front = |side: u32, lo: Vec3, hi: Vec3| {
                let a = (side / 2) as usize;
                if side & 1 == 1 {
                    lo[a]
                } else {
                    -hi[a]
                }
            };
            for side in 0..6 {
                let mut old: Vec<u32> = (first..first + count)
                    .filter(|&c| self.cards[c as usize].side() == side)
                    .collect();
                let mut new: Vec<&Layer> = layers.iter().filter(|l| l.side == side).collect();
                if old.len() != new.len() {
                    return None;
                }
                let card_front = |c: &u32| {
                    let k = &self.cards[*c as usize];
                    front(
                        side,
                        Vec3::from_slice(&k.box_min[..3]),
                        Vec3::from_slice(&k.box_max[..3]),
                    )
                };
                old.sort_by(|a, b| card_front(a).total_cmp(&card_front(b)));
                new.sort_by(|a, b| front(side, a.lo, a.hi).total_cmp(&front(side, b.lo, b.hi)));
                updates.extend(old.into_iter().zip(new).map(|(c, l)| (c, l.lo, l.hi)));
            }
        }
        Some(updates)
    }

    /// Per card: its first tile in `tiles(size)`'s list (tiles are listed card by card).
    pub fn tile_starts(&self, size: u32) -> Vec<u32> {
        let mut at = 0;
        self.cards
            .iter()
            .map(|c| {
                let first = at;
                at += (c.rect[2] / size) * (c.rect[3] / size);
                first
            })
            .collect()
    }
}
