//! Mapper state snapshots: the state that carries from frame to frame (the frame counter, the superquadric
//! tracks and the recently refused objects) encoded into a caller buffer, so a robot can persist it across a
//! reset or power loss and resume with exactly the maps it would have produced.
//!
//! Layout: magic "M2S", version, then the state as postcard (f32 values bit-exact), then a CRC-32 of all that.
//! Restoring validates everything first; a truncated, corrupted or foreign snapshot is refused.

use serde::{Deserialize, Serialize};

use crate::superquadric::Superquadric;
use crate::track::{Refusal, Track, MAX_REFUSALS};
use crate::wire::{checked_body, crc32, WireError};

/// First bytes of a snapshot.
pub const SNAPSHOT_MAGIC: [u8; 3] = *b"M2S";
/// Snapshot format version.
pub const SNAPSHOT_VERSION: u8 = 2;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Head {
    magic: [u8; 3],
    version: u8,
    frames: u32,
    tracker_frame: u32,
    next_track_id: u16,
    tracks: u16,
    refusals: u16,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct SavedRefusal {
    centre: [f32; 3],
    class: u16,
    count: u16,
    last_frame: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct SavedTrack {
    scales: [f32; 3],
    eps: [f32; 2],
    centre: [f32; 3],
    rotation: [[f32; 3]; 3],
    id: u16,
    class: u16,
    last_frame: u32,
    updates: u32,
    last_jump_deg: f32,
}

/// The persistent state of a mapper.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    /// Frames processed.
    pub frames: u32,
    /// The tracker's frame counter.
    pub tracker_frame: u32,
    /// The next track id.
    pub next_track_id: u16,
}

fn map_err(e: postcard::Error) -> WireError {
    match e {
        postcard::Error::DeserializeUnexpectedEnd => WireError::Truncated,
        postcard::Error::SerializeBufferFull => WireError::BufferTooSmall,
        _ => WireError::Malformed,
    }
}

/// Writes `state`, `tracks` and the taken `refusals` slots into `buf`; returns the bytes written.
pub fn write(buf: &mut [u8], state: &State, tracks: &[Track], refusals: &[Refusal]) -> Result<usize, WireError> {
    let head = Head {
        magic: SNAPSHOT_MAGIC,
        version: SNAPSHOT_VERSION,
        frames: state.frames,
        tracker_frame: state.tracker_frame,
        next_track_id: state.next_track_id,
        tracks: u16::try_from(tracks.len()).map_err(|_| WireError::TooManyPrimitives)?,
        refusals: u16::try_from(refusals.iter().filter(|r| r.count > 0).count())
            .map_err(|_| WireError::TooManyPrimitives)?,
    };
    let mut used = postcard::to_slice(&head, buf).map_err(map_err)?.len();
    for t in tracks {
        let saved = SavedTrack {
            scales: t.sq.scales,
            eps: t.sq.eps,
            centre: t.sq.centre,
            rotation: t.sq.rotation,
            id: t.id,
            class: t.class,
            last_frame: t.last_frame,
            updates: t.updates,
            last_jump_deg: t.last_jump_deg,
        };
        let rest = buf.get_mut(used..).ok_or(WireError::BufferTooSmall)?;
        used += postcard::to_slice(&saved, rest).map_err(map_err)?.len();
    }
    for r in refusals.iter().filter(|r| r.count > 0) {
        let saved = SavedRefusal { centre: r.centre, class: r.class, count: r.count, last_frame: r.last_frame };
        let rest = buf.get_mut(used..).ok_or(WireError::BufferTooSmall)?;
        used += postcard::to_slice(&saved, rest).map_err(map_err)?.len();
    }
    let crc = crc32(buf.get(..used).ok_or(WireError::BufferTooSmall)?);
    buf.get_mut(used..used + 4).ok_or(WireError::BufferTooSmall)?.copy_from_slice(&crc.to_le_bytes());
    Ok(used + 4)
}

/// Validates a snapshot completely and only then calls `track` for each saved track and `refusal` for each
/// saved refusal (in order); returns the state. `max_tracks` is the caller's track capacity: a snapshot with
/// more tracks (or more than [`MAX_REFUSALS`] refusals) is refused.
pub fn read(
    bytes: &[u8],
    max_tracks: usize,
    mut track: impl FnMut(Track),
    mut refusal: impl FnMut(Refusal),
) -> Result<State, WireError> {
    let body = checked_body(bytes)?;
    let parse = |f: &mut dyn FnMut(Track), g: &mut dyn FnMut(Refusal)| -> Result<State, WireError> {
        let (head, mut rest): (Head, _) = postcard::take_from_bytes(body).map_err(map_err)?;
        if head.magic != SNAPSHOT_MAGIC {
            return Err(WireError::BadMagic);
        }
        if head.version != SNAPSHOT_VERSION {
            return Err(WireError::WrongVersion(head.version));
        }
        if head.tracks as usize > max_tracks {
            return Err(WireError::BadValue("track count"));
        }
        if head.refusals as usize > MAX_REFUSALS {
            return Err(WireError::BadValue("refusal count"));
        }
        for _ in 0..head.tracks {
            let (s, r): (SavedTrack, _) = postcard::take_from_bytes(rest).map_err(map_err)?;
            rest = r;
            let sq = Superquadric { scales: s.scales, eps: s.eps, centre: s.centre, rotation: s.rotation };
            if !sq.is_within_bounds() || !s.last_jump_deg.is_finite() {
                return Err(WireError::BadValue("track"));
            }
            f(Track {
                sq,
                id: s.id,
                class: s.class,
                last_frame: s.last_frame,
                updates: s.updates,
                last_jump_deg: s.last_jump_deg,
            });
        }
        for _ in 0..head.refusals {
            let (r, more): (SavedRefusal, _) = postcard::take_from_bytes(rest).map_err(map_err)?;
            rest = more;
            if r.count == 0 || !r.centre.iter().all(|x| x.is_finite()) {
                return Err(WireError::BadValue("refusal"));
            }
            g(Refusal { centre: r.centre, class: r.class, count: r.count, last_frame: r.last_frame });
        }
        if !rest.is_empty() {
            return Err(WireError::TrailingBytes);
        }
        Ok(State { frames: head.frames, tracker_frame: head.tracker_frame, next_track_id: head.next_track_id })
    };
    parse(&mut |_| {}, &mut |_| {})?;
    parse(&mut track, &mut refusal)
}
