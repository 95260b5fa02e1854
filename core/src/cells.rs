//! The codings of plane cells on the wire besides the bitmap: run lengths ([`crate::map::CellCoding::Runs`],
//! [`CellRuns`]) and edges.
//!
//! Edge coding ([`crate::map::CellCoding::Edges`]): each row of the cell box as its transitions
//! (the column where a run of occupied cells starts, and the column just past its end), coded against the row
//! above in a bit stream, the way fax machines code scan lines (ITU-T T.6 "vertical mode").
//!
//! A row with as many transitions as the row above codes each as its shift from the one above it: 0 in one bit,
//! ±1 in three, ±2..3 in five, ±4..7 in six. Any other row (runs appearing, vanishing, or moving further) is
//! coded explicitly: its transition count and each column in 7 bits (or as many as the box width needs). The
//! first row is coded against an empty row. The boundary of a floor or a table top moves by a cell or two from
//! row to row, so most rows cost a few bits: the cabinet's floor takes about 90 bytes (median of its 58 frames)
//! instead of 180 as run lengths and 430 as a bitmap. Bits are written from the most significant bit of each
//! byte; the last byte is padded with zeros.

/// Whether cell `k` of a bitmap (bit `k % 8` of byte `k / 8`, [`crate::map::CellCoding::Bitmap`]) is set; false
/// beyond its end.
#[inline]
pub fn bit(bits: &[u8], k: usize) -> bool {
    bits.get(k / 8).is_some_and(|b| (b >> (k % 8)) & 1 == 1)
}

/// Sets cell `k` of a bitmap (nothing beyond its end).
#[inline]
pub fn set_bit(bits: &mut [u8], k: usize) {
    if let Some(b) = bits.get_mut(k / 8) {
        *b |= 1 << (k % 8);
    }
}

/// The first set cell of a bitmap in `from..to`, whole zero bytes skipped; `None` when there is none.
fn first_set(bits: &[u8], from: usize, to: usize) -> Option<usize> {
    let mut k = from;
    while k < to {
        let rest = bits.get(k / 8).copied().unwrap_or(0) >> (k % 8);
        if rest != 0 {
            let c = k + rest.trailing_zeros() as usize;
            return (c < to).then_some(c);
        }
        k = (k / 8 + 1) * 8;
    }
    None
}

/// The last set cell of a bitmap in `from..to`, whole zero bytes skipped; `None` when there is none.
fn last_set(bits: &[u8], from: usize, to: usize) -> Option<usize> {
    let mut end = to;
    while end > from {
        let k = end - 1;
        // Bits 0..=k % 8 of k's byte.
        let below = bits.get(k / 8).copied().unwrap_or(0) & (0xFF >> (7 - k % 8));
        if below != 0 {
            let c = (k / 8) * 8 + 7 - below.leading_zeros() as usize;
            return (c >= from).then_some(c);
        }
        end = (k / 8) * 8;
    }
    None
}

/// The smallest (i0, j0, i1, j1) box (columns, rows, inclusive) holding every set cell of a `width` × `height`
/// bitmap ([`bit`]), `None` when none is set: each row's first and last set cell, whole zero bytes skipped (a
/// plane's grid is mostly empty; bit by bit, the box was 3.5 % of redkitchen's superquadric stage).
pub fn bitmap_box(bits: &[u8], width: usize, height: usize) -> Option<(usize, usize, usize, usize)> {
    let mut b: Option<(usize, usize, usize, usize)> = None;
    for j in 0..height {
        let row = j * width;
        let (Some(first), Some(last)) = (first_set(bits, row, row + width), last_set(bits, row, row + width)) else {
            continue;
        };
        let (i0, i1) = (first - row, last - row);
        b = Some(match b {
            None => (i0, j, i1, j),
            Some((a0, b0, a1, _)) => (a0.min(i0), b0, a1.max(i1), j),
        });
    }
    b
}

/// The run lengths of [`crate::map::CellCoding::Runs`] bytes, in order; it stops at the end or at a malformed
/// varint (more than three bytes), which [`crate::wire::decode`] refuses before a map is handed out.
#[derive(Debug, Clone)]
pub struct CellRuns<'a> {
    bytes: &'a [u8],
}

impl<'a> CellRuns<'a> {
    /// The runs of `bytes`.
    pub fn new(bytes: &'a [u8]) -> Self {
        CellRuns { bytes }
    }

    /// Whether every byte was consumed by well-formed varints (after iterating to the end).
    pub fn is_exhausted(&self) -> bool {
        self.bytes.is_empty()
    }
}

impl Iterator for CellRuns<'_> {
    type Item = u32;

    fn next(&mut self) -> Option<u32> {
        let mut value = 0u32;
        for (k, &b) in self.bytes.iter().enumerate().take(3) {
            value |= u32::from(b & 0x7f) << (7 * k);
            if b & 0x80 == 0 {
                self.bytes = self.bytes.get(k + 1..).unwrap_or(&[]);
                return Some(value);
            }
        }
        None
    }
}

/// Appends run length `n` as an unsigned LEB128 varint to `out` at `*len`; `false` when it does not fit.
pub fn push_run(out: &mut [u8], len: &mut usize, mut n: u32) -> bool {
    loop {
        let Some(slot) = out.get_mut(*len) else { return false };
        let more = n >= 0x80;
        *slot = (n & 0x7f) as u8 | if more { 0x80 } else { 0 };
        *len += 1;
        n >>= 7;
        if !more {
            return true;
        }
    }
}

/// The run lengths ([`crate::map::CellCoding::Runs`]) of the first `cells` bits of `bits` into `out`: the bytes written, or
/// `None` when they do not fit.
pub fn run_lengths(bits: &[u8], cells: usize, out: &mut [u8]) -> Option<usize> {
    let (mut len, mut run, mut set) = (0usize, 0u32, false);
    for k in 0..cells {
        let is_set = bit(bits, k);
        if is_set != set {
            if !push_run(out, &mut len, run) {
                return None;
            }
            (run, set) = (0, is_set);
        }
        run += 1;
    }
    push_run(out, &mut len, run).then_some(len)
}

/// Whether `bytes` are well-formed run lengths covering exactly `cells` cells, each run but the first non-empty.
pub fn runs_cover(bytes: &[u8], cells: usize) -> bool {
    let mut runs = CellRuns::new(bytes);
    let mut total = 0usize;
    for (r, run) in runs.by_ref().enumerate() {
        if run == 0 && r > 0 {
            return false;
        }
        total += run as usize;
        if total > cells {
            return false;
        }
    }
    runs.is_exhausted() && total == cells
}

/// Most transitions in one row: boxes up to 255 cells wide.
pub const MAX_EDGES: usize = 256;

/// Writes bits into a caller's buffer, most significant first.
struct BitWriter<'a> {
    out: &'a mut [u8],
    bits: usize,
}

impl BitWriter<'_> {
    /// Appends the low `n` bits of `value`, highest first; `false` when the buffer is full.
    fn put(&mut self, value: u32, n: u32) -> bool {
        for k in (0..n).rev() {
            let Some(byte) = self.out.get_mut(self.bits / 8) else { return false };
            if self.bits.is_multiple_of(8) {
                *byte = 0;
            }
            if (value >> k) & 1 == 1 {
                *byte |= 0x80 >> (self.bits % 8);
            }
            self.bits += 1;
        }
        true
    }
}

/// Reads bits written by [`BitWriter`].
#[derive(Debug, Clone)]
struct BitReader<'a> {
    bytes: &'a [u8],
    bits: usize,
}

impl BitReader<'_> {
    fn bit(&mut self) -> Option<u32> {
        let byte = self.bytes.get(self.bits / 8)?;
        let b = (byte >> (7 - self.bits % 8)) & 1;
        self.bits += 1;
        Some(b as u32)
    }

    fn take(&mut self, n: u32) -> Option<u32> {
        (0..n).try_fold(0u32, |v, _| Some((v << 1) | self.bit()?))
    }
}

/// Bits of a column index or transition count in an explicit row of a box `width` cells wide.
fn field_bits(width: usize) -> u32 {
    usize::BITS - (width + 1).leading_zeros()
}

/// The transitions of row `j` of a `width`-wide bitmap (bit k % 8 of byte k / 8 for cell k) into `out`.
fn row_edges(bits: &[u8], width: usize, j: usize, out: &mut [u8; MAX_EDGES]) -> usize {
    let mut n = 0;
    let mut inside = false;
    for i in 0..=width {
        let k = j * width + i;
        let set = i < width && bit(bits, k);
        if set != inside {
            if let Some(slot) = out.get_mut(n) {
                *slot = i as u8;
            }
            n += 1;
            inside = set;
        }
    }
    n
}

/// Codes the `width × height` bitmap `bits` into `out`: the bytes written, or `None` when they do not fit (or
/// the box is wider than 255 cells).
pub fn encode_edges(bits: &[u8], width: usize, height: usize, out: &mut [u8]) -> Option<usize> {
    if width > MAX_EDGES - 1 {
        return None;
    }
    let mut w = BitWriter { out, bits: 0 };
    let field = field_bits(width);
    let (mut above, mut row) = ([0u8; MAX_EDGES], [0u8; MAX_EDGES]);
    let mut n_above = 0;
    for j in 0..height {
        let n = row_edges(bits, width, j, &mut row);
        let shifts = row.iter().zip(&above).take(n).map(|(&c, &p)| c as i32 - p as i32);
        let vertical = n == n_above && shifts.clone().all(|d| d.abs() <= 7);
        if vertical {
            if !w.put(0, 1) {
                return None;
            }
            for d in shifts {
                let (sign, m) = (u32::from(d < 0), d.unsigned_abs());
                let ok = match m {
                    0 => w.put(0, 1),
                    1 => w.put(0b10, 2) && w.put(sign, 1),
                    2..=3 => w.put(0b110, 3) && w.put(sign, 1) && w.put(m - 2, 1),
                    _ => w.put(0b111, 3) && w.put(sign, 1) && w.put(m - 4, 2),
                };
                if !ok {
                    return None;
                }
            }
        } else {
            if !(w.put(1, 1) && w.put(n as u32, field)) {
                return None;
            }
            for &c in row.iter().take(n) {
                if !w.put(c as u32, field) {
                    return None;
                }
            }
        }
        (above, n_above) = (row, n);
    }
    Some(w.bits.div_ceil(8))
}

/// Decodes an edge-coded cell box row by row ([`EdgeRows::next_row`]).
#[derive(Debug, Clone)]
pub struct EdgeRows<'a> {
    bits: BitReader<'a>,
    width: usize,
    above: [u8; MAX_EDGES],
    n_above: usize,
}

impl<'a> EdgeRows<'a> {
    /// The rows of a box `width` cells wide coded in `bytes`.
    pub fn new(bytes: &'a [u8], width: usize) -> Self {
        EdgeRows { bits: BitReader { bytes, bits: 0 }, width, above: [0; MAX_EDGES], n_above: 0 }
    }

    /// The next row's transitions into `out` (strictly increasing columns in 0..=width, an even count): their
    /// number, or `None` when the stream is malformed or ends.
    pub fn next_row(&mut self, out: &mut [u8; MAX_EDGES]) -> Option<usize> {
        if self.width > MAX_EDGES - 1 {
            return None;
        }
        let field = field_bits(self.width);
        let n = if self.bits.bit()? == 0 {
            let above = self.above;
            for (o, &p) in out.iter_mut().zip(&above).take(self.n_above) {
                *o = u8::try_from(p as i32 + self.shift()?).ok()?;
            }
            self.n_above
        } else {
            let n = self.bits.take(field)? as usize;
            if n > MAX_EDGES {
                return None;
            }
            for o in out.iter_mut().take(n) {
                *o = u8::try_from(self.bits.take(field)?).ok()?;
            }
            n
        };
        self.accept(out, n)
    }

    /// One shift of a vertical row: '0' → 0, '10' s → ±1, '110' s b → ±(2 + b), '111' s bb → ±(4 + bb).
    fn shift(&mut self) -> Option<i32> {
        let class = if self.bits.bit()? == 0 {
            return Some(0);
        } else if self.bits.bit()? == 0 {
            1
        } else if self.bits.bit()? == 0 {
            2
        } else {
            4
        };
        let sign = self.bits.bit()?;
        let m = class + self.bits.take(class / 2)?;
        Some(if sign == 1 { -(m as i32) } else { m as i32 })
    }

    /// Checks a decoded row and makes it the row above the next.
    fn accept(&mut self, row: &[u8; MAX_EDGES], n: usize) -> Option<usize> {
        let edges = row.get(..n)?;
        let increasing = edges.windows(2).all(|p| matches!(p, [a, b] if a < b));
        let inside = edges.last().is_none_or(|&e| e as usize <= self.width);
        if !n.is_multiple_of(2) || !increasing || !inside {
            return None;
        }
        self.above = *row;
        self.n_above = n;
        Some(n)
    }

    /// Whether every byte was used, up to zero padding of the last (after the last row).
    pub fn is_exhausted(&self) -> bool {
        let used = self.bits.bits.div_ceil(8);
        let pad_zero = match self.bits.bytes.get(self.bits.bits / 8) {
            Some(b) if !self.bits.bits.is_multiple_of(8) => b & (0xff >> (self.bits.bits % 8)) == 0,
            _ => true,
        };
        used == self.bits.bytes.len() && pad_zero
    }
}

/// Whether `bytes` code exactly `height` valid rows of a box `width` cells wide, with nothing but zero padding
/// after the last.
pub fn edges_cover(bytes: &[u8], width: usize, height: usize) -> bool {
    let mut rows = EdgeRows::new(bytes, width);
    let mut row = [0u8; MAX_EDGES];
    (0..height).all(|_| rows.next_row(&mut row).is_some()) && rows.is_exhausted()
}

/// Calls `f(column, row)` for every occupied cell of an edge-coded box, in row-major order (stops at a malformed
/// row, which [`crate::wire::decode`] refuses before a map is handed out).
pub fn for_each_edge_cell(bytes: &[u8], width: usize, height: usize, mut f: impl FnMut(usize, usize)) {
    let mut rows = EdgeRows::new(bytes, width);
    let mut row = [0u8; MAX_EDGES];
    for j in 0..height {
        let Some(n) = rows.next_row(&mut row) else { return };
        for pair in row.get(..n).unwrap_or(&[]).chunks_exact(2) {
            if let [start, end] = pair {
                for i in *start as usize..*end as usize {
                    f(i, j);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// The byte-wise box is the bit-by-bit box on bitmaps of widths that do and do not fill whole bytes: empty,
    /// one cell (every position of a 13 × 5 grid), single cells at the grid's corners, and pseudo-random sparse
    /// and dense grids.
    #[test]
    fn bitmap_box_is_the_box_of_the_set_bits() {
        let brute = |bits: &[u8], w: usize, h: usize| {
            let mut b: Option<(usize, usize, usize, usize)> = None;
            for j in 0..h {
                for i in 0..w {
                    if bit(bits, j * w + i) {
                        b = Some(
                            b.map_or((i, j, i, j), |(a0, b0, a1, b1)| (a0.min(i), b0.min(j), a1.max(i), b1.max(j))),
                        );
                    }
                }
            }
            b
        };
        assert_eq!(bitmap_box(&bitmap(80, 80, |_, _| false), 80, 80), None);
        for (i, j) in (0..13).flat_map(|i| (0..5).map(move |j| (i, j))) {
            let bits = bitmap(13, 5, |x, y| (x, y) == (i, j));
            assert_eq!(bitmap_box(&bits, 13, 5), Some((i, j, i, j)), "cell ({i}, {j})");
        }
        let mut state = 12345u32;
        let mut next = move || {
            state = state.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            state >> 16
        };
        let mut checked = 0;
        for (w, h) in [(80, 80), (13, 7), (9, 31), (1, 17), (64, 3)] {
            let corners = bitmap(w, h, |x, y| (x == 0 || x == w - 1) && (y == 0 || y == h - 1) && x == y % w);
            assert_eq!(bitmap_box(&corners, w, h), brute(&corners, w, h));
            for density in [2u32, 50, 500, 32_000] {
                let cells: std::vec::Vec<bool> = (0..w * h).map(|_| next() % 32_768 < density).collect();
                let bits = bitmap(w, h, |x, y| cells[y * w + x]);
                assert_eq!(bitmap_box(&bits, w, h), brute(&bits, w, h), "{w} × {h}, density {density}");
                checked += 1;
            }
        }
        assert_eq!(checked, 20);
    }

    fn bitmap(w: usize, h: usize, set: impl Fn(usize, usize) -> bool) -> std::vec::Vec<u8> {
        let mut bits = std::vec![0u8; (w * h).div_ceil(8)];
        for j in 0..h {
            for i in 0..w {
                if set(i, j) {
                    bits[(j * w + i) / 8] |= 1 << ((j * w + i) % 8);
                }
            }
        }
        bits
    }

    fn round_trip(w: usize, h: usize, set: impl Fn(usize, usize) -> bool + Copy) -> usize {
        let bits = bitmap(w, h, set);
        let mut out = [0u8; 4096];
        let n = encode_edges(&bits, w, h, &mut out).unwrap();
        assert!(edges_cover(&out[..n], w, h));
        let mut got = std::vec::Vec::new();
        for_each_edge_cell(&out[..n], w, h, |i, j| got.push((i, j)));
        let want: std::vec::Vec<_> =
            (0..h).flat_map(|j| (0..w).map(move |i| (i, j))).filter(|&(i, j)| set(i, j)).collect();
        assert_eq!(got, want, "{w} x {h}");
        // Any shorter prefix, and any extra byte, is refused.
        assert!(!edges_cover(&out[..n.saturating_sub(1)], w, h) || n == 0 || h == 0);
        let mut longer = out[..n].to_vec();
        longer.push(0);
        assert!(!edges_cover(&longer, w, h));
        n
    }

    #[test]
    fn edges_round_trip_shapes_and_stay_small_for_blobs() {
        // A disc with a hole: vertical rows except where the hole opens and closes.
        let disc = |i: usize, j: usize| {
            let (x, y) = (i as f32 - 30.0, j as f32 - 28.0);
            x * x + y * y <= 576.0 && !((-4.0..4.0).contains(&x) && (-6.0..3.0).contains(&y))
        };
        let n = round_trip(60, 56, disc);
        assert!(n < 60, "{n} bytes for a 48-cell disc");
        round_trip(20, 12, |i, j| (i + j) % 2 == 0);
        round_trip(80, 80, |_, _| true);
        round_trip(16, 16, |_, _| false);
        round_trip(1, 1, |_, _| true);
        round_trip(7, 5, |i, j| i == 6 && j == 4);
        // Shifts of every size between rows: a diagonal band moving 0..9 cells per row.
        round_trip(80, 12, |i, j| {
            let s = j * (j + 1) / 2;
            (s..s + 5).contains(&i)
        });
    }

    #[test]
    fn malformed_edges_are_refused() {
        // Explicit row (field 4 bits for width 8): count 3 (odd) is refused; decreasing columns are refused;
        // a column beyond the width is refused.
        // Bits: explicit 1, count 0011, columns 0001, 0010, 0100 (then padding).
        let odd = [0b1001_1000, 0b1001_0010, 0b0000_0000];
        assert!(!edges_cover(&odd, 8, 1));
        let mut out = [0u8; 8];
        let mut w = BitWriter { out: &mut out, bits: 0 };
        assert!(w.put(1, 1) && w.put(2, 4) && w.put(5, 4) && w.put(3, 4));
        assert!(!edges_cover(&out[..2], 8, 1));
        let mut out = [0u8; 8];
        let mut w = BitWriter { out: &mut out, bits: 0 };
        assert!(w.put(1, 1) && w.put(2, 4) && w.put(3, 4) && w.put(9, 4));
        assert!(!edges_cover(&out[..2], 8, 1));
        // A shift that leaves the row's columns out of order or below 0.
        let mut out = [0u8; 8];
        let mut w = BitWriter { out: &mut out, bits: 0 };
        assert!(
            w.put(1, 1) && w.put(2, 4) && w.put(1, 4) && w.put(2, 4) && w.put(0, 1) && w.put(0b10, 2) && w.put(1, 1)
        );
        let at_zero = out;
        let mut w = BitWriter { out: &mut out, bits: 17 };
        // Shifts −1, −2: columns 0, 0.
        assert!(w.put(0b110, 3) && w.put(1, 1) && w.put(0, 1));
        assert!(!edges_cover(&out[..3], 8, 2));
        // Shifts −1, −1: columns 0, 1, a valid row.
        let mut ok = at_zero;
        let mut w = BitWriter { out: &mut ok, bits: 17 };
        assert!(w.put(0b10, 2) && w.put(1, 1));
        assert!(edges_cover(&ok[..3], 8, 2));
        // Wider than 255 cells: not coded.
        assert_eq!(encode_edges(&[0u8; 64], 256, 1, &mut [0u8; 64]), None);
    }

    #[test]
    fn run_lengths_cover_their_cells_exactly() {
        // Cells 0..12 with 2..5 and 9 set: runs 2, 3, 4, 1, 2.
        let bits = [0b0001_1100u8, 0b0000_0010];
        let mut out = [0u8; 8];
        let n = run_lengths(&bits, 12, &mut out).unwrap();
        assert_eq!(&out[..n], &[2, 3, 4, 1, 2]);
        assert!(runs_cover(&out[..n], 12));
        // A first set cell starts with an empty run; a long run takes two varint bytes.
        let mut out = [0u8; 8];
        let n = run_lengths(&[0xff; 40], 300, &mut out).unwrap();
        assert_eq!(&out[..n], &[0, 0xac, 0x02]);
        assert!(runs_cover(&out[..n], 300));
        // Too little room: None.
        assert_eq!(run_lengths(&bits, 12, &mut [0u8; 4]), None);
        // Refused: short, long, an empty run after the first, an unterminated varint, trailing garbage.
        assert!(!runs_cover(&[2, 3, 4, 1, 1], 12));
        assert!(!runs_cover(&[2, 3, 4, 1, 3], 12));
        assert!(!runs_cover(&[2, 0, 4, 1, 5], 12));
        assert!(!runs_cover(&[0x8c], 12));
        assert!(!runs_cover(&[12, 0x80, 0x80, 0x80, 0x01], 12));
        assert!(runs_cover(&[12], 12));
    }
}
