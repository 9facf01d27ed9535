//! Lines of sight shared by the renders of one frame's sub-bands. Each
//! sub-band of a spectral render lays out the same caps and tests the same
//! surface points against the same camera; only the reflectance differs.
//! A march through the DEM ([`super::sight::Relief::clears`]) depends on
//! its start point, its direction and the relief alone, so the first
//! sub-band's answers are kept, keyed by the exact bits of those inputs,
//! and the later ones read them back: the same answer, without the march.
//!
//! Likewise how the camera sees each cap corner and each corner of the
//! parts of caps cut at an occlusion edge ([`Frame::sight`]: the surface
//! normal, the horizon map and the march): a leaf of caps asks for them in
//! the same order in every sub-band, so the first one's answers are kept
//! as the leaf's tape ([`SightTape`]) and read back in order (a hash
//! lookup per corner cost as much as computing it: a cache miss each).
//! The memo is on only between [`SightMemo::begin`] and
//! [`SightMemo::end`] (a frame's band loop), and it forgets everything
//! when the relief changes (another DEM, tile set, radius or bound).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::{Arc, Mutex};

use glam::DVec3;

#[cfg(doc)]
use super::caps::Frame;
use super::occlusion::Sight;
use super::sight::Relief;
use crate::scene::Body;

/// Locks the answers are spread over (the workers seldom wait).
const SHARDS: usize = 16;

/// A march's exact inputs: the bits of its start point and direction.
type MarchKey = [u64; 6];

/// A point's exact direction (bits).
type PointKey = [u64; 3];

/// A leaf of caps: its cell's bits, its caps along θ and s, whether the
/// frame applied its horizon map (which [`Frame::sight`] reads), and the
/// camera's position and the body's axes in the lune's frame (bits): a
/// tape is read back only for the same leaf of the same view.
pub type LeafKey = [u64; 19];

/// The sights a leaf asked for, in order.
type Tape = Vec<(PointKey, Sight)>;

/// Which relief the kept answers belong to: the height map's and tiles'
/// addresses (alive for the frame) and the radius and bound bits.
type ReliefId = (usize, usize, u64, u64);

/// Multiply–xorshift hash of the key's words (the std SipHash costs as
/// much as a short march step).
#[derive(Default)]
struct MixHasher(u64);

impl Hasher for MixHasher {
    fn finish(&self) -> u64 {
        let h = self.0 ^ (self.0 >> 29);
        h.wrapping_mul(0xbf58_476d_1ce4_e5b9) ^ (h >> 32)
    }
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(word));
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(23) ^ v).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    }
    fn write_usize(&mut self, v: usize) {
        self.write_u64(v as u64);
    }
}

/// One lock's share of the answers.
#[derive(Default)]
struct Shard {
    marches: HashMap<MarchKey, bool, BuildHasherDefault<MixHasher>>,
    tapes: HashMap<LeafKey, Arc<Tape>, BuildHasherDefault<MixHasher>>,
}

/// The shard of a key: bits the maps' own buckets and tags do not use.
fn shard_of(words: &[u64]) -> usize {
    let mut h = MixHasher::default();
    words.iter().for_each(|&w| h.write_u64(w));
    (h.finish() >> 40) as usize % SHARDS
}

/// Kept march answers, shared by the workers of one frame's renders.
#[derive(Default)]
pub struct SightMemo {
    on: bool,
    relief: Option<ReliefId>,
    shards: [Mutex<Shard>; SHARDS],
}

impl SightMemo {
    /// Starts keeping answers: the renders until [`Self::end`] are one
    /// frame's sub-bands (one body, one state).
    pub fn begin(&mut self) {
        self.end();
        self.on = true;
    }

    /// Stops keeping answers and drops them. The maps keep their
    /// capacity: the next frame's band loop fills them again without
    /// regrowing (a facility run's frames ask for similar counts).
    pub fn end(&mut self) {
        self.on = false;
        self.relief = None;
        self.forget();
    }

    fn forget(&mut self) {
        for shard in &mut self.shards {
            let shard = shard.get_mut().unwrap_or_else(|e| e.into_inner());
            shard.marches.clear();
            shard.tapes.clear();
        }
    }

    /// Before a render of `body`: forgets every answer if they were for
    /// another relief. Returns the memo to consult, or None when off.
    pub fn prepare(&mut self, body: &Body) -> Option<&SightMemo> {
        if !self.on {
            return None;
        }
        let relief = &body.relief;
        let id = (
            relief
                .height
                .as_ref()
                .map_or(0, |h| &h.0 as *const _ as usize),
            relief
                .height_tiles
                .as_ref()
                .map_or(0, |t| std::sync::Arc::as_ptr(t) as usize),
            body.radius.to_bits(),
            relief.height_bound.to_bits(),
        );
        if self.relief != Some(id) {
            self.forget();
            self.relief = Some(id);
        }
        Some(self)
    }

    /// How many march answers and leaf tapes it holds.
    pub fn kept(&self) -> (usize, usize) {
        self.shards.iter().fold((0, 0), |(m, t), shard| {
            let shard = lock(shard);
            (m + shard.marches.len(), t + shard.tapes.len())
        })
    }

    /// `relief.clears(p, v)`, read back when an earlier render of the
    /// frame asked the same.
    pub fn clears(&self, relief: &Relief, p: DVec3, v: DVec3) -> bool {
        let key = [p.x, p.y, p.z, v.x, v.y, v.z].map(f64::to_bits);
        let shard = &self.shards[shard_of(&key)];
        let kept = lock(shard).marches.get(&key).copied();
        if let Some(clear) = kept {
            return clear;
        }
        let clear = relief.clears(p, v);
        lock(shard).marches.insert(key, clear);
        clear
    }

    /// The tape kept for the leaf `key`, if an earlier render made one.
    fn tape(&self, key: &LeafKey) -> Option<Arc<Tape>> {
        lock(&self.shards[shard_of(key)]).tapes.get(key).cloned()
    }

    /// Keeps the tape `tape` of the leaf `key`.
    fn keep_tape(&self, key: LeafKey, tape: Tape) {
        lock(&self.shards[shard_of(&key)])
            .tapes
            .insert(key, Arc::new(tape));
    }
}

/// One worker's sights of the leaf it grids: read back from the leaf's
/// tape where an earlier sub-band made one, else recorded for the next.
#[derive(Default)]
pub struct SightTape {
    /// Whether the frame keeps sights at all.
    active: bool,
    key: LeafKey,
    replay: Option<Arc<Tape>>,
    next: usize,
    record: Tape,
}

impl SightTape {
    /// Starts the leaf `key` of a frame whose memo is `memo`.
    pub fn start(&mut self, memo: Option<&SightMemo>, key: LeafKey) {
        self.active = memo.is_some();
        self.key = key;
        self.replay = memo.and_then(|m| m.tape(&key));
        self.next = 0;
        self.record.clear();
    }

    /// Ends the leaf: a leaf computed afresh leaves its tape in `memo`.
    pub fn finish(&mut self, memo: Option<&SightMemo>) {
        if let (Some(memo), None, true) = (memo, &self.replay, self.active) {
            memo.keep_tape(self.key, std::mem::take(&mut self.record));
        }
        self.active = false;
    }

    /// The sight of the point over `n_local`: the tape's next answer when
    /// it is for the same point, else `sight()` (recorded). A tape that
    /// disagrees is dropped for the rest of the leaf.
    pub fn sight(&mut self, n_local: DVec3, sight: impl FnOnce() -> Sight) -> Sight {
        if !self.active {
            return sight();
        }
        let key = [n_local.x, n_local.y, n_local.z].map(f64::to_bits);
        if let Some(tape) = &self.replay {
            match tape.get(self.next) {
                Some(&(k, s)) if k == key => {
                    self.next += 1;
                    return s;
                }
                _ => {
                    // Not the leaf it was recorded for: compute the rest,
                    // keep nothing.
                    self.active = false;
                    return sight();
                }
            }
        }
        let s = sight();
        self.record.push((key, s));
        s
    }
}

/// The shard, whatever a panicking worker left (its answers are whole).
fn lock(shard: &Mutex<Shard>) -> std::sync::MutexGuard<'_, Shard> {
    shard.lock().unwrap_or_else(|e| e.into_inner())
}
