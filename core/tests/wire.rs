//! The map wire format: round trips, golden bytes, quantisation error, and corrupted input.

use m2smap_core::linalg::{self, Vec3};
use m2smap_core::map::{CellBits, CellCoding, MapGmm, MapPlane, MapSq, Primitive};
use m2smap_core::superquadric::Superquadric;
use m2smap_core::wire::{self, WireError};

/// A fixed map: one plane with an L of occupied cells, one superquadric, two Gaussians.
fn with_map<R>(f: impl FnOnce(&[Primitive<'_>]) -> R) -> R {
    let mut bits = [0u8; 32]; // 16 x 16 grid
    for k in 0..16 {
        bits[(3 * 16 + k) / 8] |= 1 << ((3 * 16 + k) % 8);
        bits[(k * 16 + 5) / 8] |= 1 << ((k * 16 + 5) % 8);
    }
    let prims = [
        Primitive::Plane(MapPlane {
            centroid: [0.12, 0.81, 2.31],
            rotation: linalg::rotation_from_vector([1.2, 0.1, -0.3]),
            sigmas: [0.62, 0.41, 0.006],
            eigen_ratio: 0.0001,
            colour: [140, 150, 130],
            cluster: 3,
            g_p: 0.05,
            cells: CellBits { a0: -8, b0: -8, width: 16, height: 16, coding: CellCoding::Bitmap, bits: &bits },
        }),
        Primitive::Sq(MapSq {
            sq: Superquadric {
                scales: [0.23, 0.29, 0.36],
                eps: [0.12, 0.31],
                centre: [-0.4, 0.1, 1.75],
                rotation: linalg::rotation_from_vector([0.2, -0.9, 0.4]),
            },
            instance: 1,
            class: 0,
            score: 0.93,
            track: 7,
            partial: false,
        }),
        Primitive::Gmm(MapGmm {
            mean: [0.5, -0.2, 1.9],
            rotation: linalg::rotation_from_vector([-0.5, 0.3, 2.0]),
            sigmas: [0.05, 0.02, 0.003],
            count: 420,
            colour: [200, 60, 50],
            instance: 0,
            class: 0,
            score: 0.0,
            support_ratio: 0.12,
        }),
        Primitive::Gmm(MapGmm {
            mean: [-1.1, 0.4, 2.8],
            rotation: linalg::IDENTITY,
            sigmas: [0.08, 0.07, 0.01],
            count: 77,
            colour: [10, 20, 30],
            instance: 2,
            class: 4,
            score: 0.7,
            support_ratio: 0.83,
        }),
    ];
    f(&prims)
}

fn encode(prims: &[Primitive<'_>]) -> Vec<u8> {
    let mut buf = vec![0u8; 4096];
    let n = wire::encode(&mut buf, 42, |sink| prims.iter().for_each(&mut *sink)).unwrap();
    buf.truncate(n);
    buf
}

fn samples(p: &Primitive<'_>) -> Vec<Vec3> {
    let mut v = Vec::new();
    p.for_each_sample(|x| v.push(x));
    v
}

#[test]
fn round_trip_is_identical_and_within_a_millimetre() {
    with_map(|prims| {
        let bytes = encode(prims);
        let mut decoded = Vec::new();
        let header = wire::decode(&bytes, |p| decoded.push(p)).unwrap();
        assert_eq!((header.frame, header.planes, header.sqs, header.gmms), (42, 1, 1, 2));
        assert_eq!(decoded.len(), 4);
        // Re-encoding the decoded map gives the same bytes.
        assert_eq!(encode(&decoded), bytes);
        // Every reconstruction sample lies within 1 mm of one of the unquantised map's, and vice versa (a
        // superquadric sample at the visibility boundary may flip sides; counts agree to 1 %).
        let mut worst = 0.0f32;
        let nearest =
            |p: Vec3, set: &[Vec3]| set.iter().map(|q| linalg::norm(linalg::sub(p, *q))).fold(f32::MAX, f32::min);
        for (a, b) in prims.iter().zip(&decoded) {
            let (sa, sb) = (samples(a), samples(b));
            assert!(sa.len().abs_diff(sb.len()) * 100 <= sa.len(), "{} vs {} samples", sa.len(), sb.len());
            for x in &sb {
                worst = worst.max(nearest(*x, &sa));
            }
            for x in &sa {
                worst = worst.max(nearest(*x, &sb));
            }
        }
        println!("{} bytes for 4 primitives; worst sample shift {:.3} mm", bytes.len(), worst * 1000.0);
        assert!(worst < 1e-3, "quantisation moved a sample by {worst} m");
        // Semantic attributes survive.
        match (&decoded[1], &decoded[3]) {
            (Primitive::Sq(s), Primitive::Gmm(g)) => {
                assert_eq!((s.instance, s.track), (1, 7));
                assert!((s.score - 0.93).abs() < 0.003);
                assert_eq!((g.instance, g.class, g.count), (2, 4, 77));
                assert!((g.support_ratio - 0.83).abs() < 0.003);
            }
            other => panic!("unexpected order {other:?}"),
        }
    });
}

#[test]
fn golden_bytes() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../fixtures/golden/wire_v2.hex");
    let hex: String = with_map(encode).iter().map(|b| format!("{b:02x}")).collect();
    if std::env::var("M2SMAP_BLESS").is_ok_and(|v| v == "1") {
        std::fs::write(path, format!("{hex}\n")).unwrap();
    }
    let want = std::fs::read_to_string(path).expect("golden file; bless with M2SMAP_BLESS=1");
    assert_eq!(hex, want.trim(), "wire format changed: bump VERSION or re-bless with a reason");
}

#[test]
fn truncated_flipped_and_foreign_maps_are_errors() {
    let bytes = with_map(encode);
    for n in 0..bytes.len() {
        assert!(wire::decode(&bytes[..n], |_| panic!("no primitive from a truncated map")).is_err(), "prefix {n}");
    }
    for i in 0..bytes.len() {
        for bit in 0..8 {
            let mut b = bytes.clone();
            b[i] ^= 1 << bit;
            assert!(wire::decode(&b, |_| panic!("no primitive from a corrupted map")).is_err(), "byte {i} bit {bit}");
        }
    }
    // A well-formed map of another version (valid checksum) is refused by version.
    let mut b = bytes.clone();
    b[2] = 3;
    let n = b.len() - 4;
    let crc = wire::crc32(&b[..n]).to_le_bytes();
    b[n..].copy_from_slice(&crc);
    assert_eq!(wire::decode(&b, |_| {}).unwrap_err(), WireError::WrongVersion(3));
    // The same map as version 1 wrote it (before run-length plane cells) is refused by version.
    let v1 = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../fixtures/golden/wire_v1.hex")).unwrap();
    let v1: Vec<u8> =
        (0..v1.trim().len() / 2).map(|i| u8::from_str_radix(&v1[2 * i..2 * i + 2], 16).unwrap()).collect();
    assert_eq!(wire::decode(&v1, |_| {}).unwrap_err(), WireError::WrongVersion(1));
    // Trailing bytes inside a valid checksum.
    let mut b = bytes[..bytes.len() - 4].to_vec();
    b.push(0);
    let crc = wire::crc32(&b).to_le_bytes();
    b.extend_from_slice(&crc);
    assert_eq!(wire::decode(&b, |_| {}).unwrap_err(), WireError::TrailingBytes);
}

#[test]
fn random_mutations_never_panic() {
    let bytes = with_map(encode);
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let mut accepted_changed = 0;
    for _ in 0..20_000 {
        let mut b = bytes.clone();
        match rnd() % 4 {
            0 => {
                let i = (rnd() as usize) % b.len();
                b[i] = rnd() as u8;
            }
            1 => b.truncate((rnd() as usize) % b.len()),
            2 => b.insert((rnd() as usize) % b.len(), rnd() as u8),
            _ => {
                // Mutate the body and fix the checksum: exercises the field validation.
                let n = b.len() - 4;
                let i = (rnd() as usize) % n;
                b[i] = rnd() as u8;
                let crc = wire::crc32(&b[..n]).to_le_bytes();
                b[n..].copy_from_slice(&crc);
            }
        }
        let mut count = 0;
        if wire::decode(&b, |_| count += 1).is_ok() && b != bytes {
            accepted_changed += 1;
            assert!(count <= 4 + 1000);
        }
    }
    println!("{accepted_changed} of 20000 mutated maps still decoded (checksum-fixed body edits that stay valid)");
}

#[test]
fn a_small_buffer_is_an_error() {
    with_map(|prims| {
        let full = encode(prims).len();
        for n in 0..full {
            let mut buf = vec![0u8; n];
            assert_eq!(
                wire::encode(&mut buf, 42, |sink| prims.iter().for_each(&mut *sink)),
                Err(WireError::BufferTooSmall),
                "buffer {n}"
            );
        }
    });
}

/// The CRC-32 behind maps and snapshots is the standard one (IEEE 802.3, reflected): its check value for the
/// ASCII bytes "123456789" is 0xCBF43926, and feeding the bytes in two parts gives the same CRC.
#[test]
fn crc32_has_the_standard_check_value() {
    assert_eq!(wire::crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(wire::crc32(b""), 0);
    let (a, b) = b"123456789".split_at(4);
    assert_eq!(!wire::crc32_update(wire::crc32_update(0xFFFF_FFFF, a), b), 0xCBF4_3926);
}

/// A plane whose cells are `set(i, j)` on a `w × h` grid, as the mapper hands it to the encoder (a bitmap).
fn plane_map(w: usize, h: usize, set: impl Fn(usize, usize) -> bool) -> (Vec<u8>, Vec<(usize, usize)>, usize) {
    let mut bits = vec![0u8; (w * h).div_ceil(8)];
    let mut cells = Vec::new();
    for j in 0..h {
        for i in 0..w {
            if set(i, j) {
                bits[(j * w + i) / 8] |= 1 << ((j * w + i) % 8);
                cells.push((i, j));
            }
        }
    }
    let plane = Primitive::Plane(MapPlane {
        centroid: [0.0, 0.3, 2.0],
        rotation: linalg::IDENTITY,
        sigmas: [0.5, 0.4, 0.004],
        eigen_ratio: 0.001,
        colour: [90, 90, 90],
        cluster: 1,
        g_p: 0.05,
        cells: CellBits {
            a0: -40,
            b0: -40,
            width: w as u16,
            height: h as u16,
            coding: CellCoding::Bitmap,
            bits: &bits,
        },
    });
    (encode(&[plane]), cells, bits.len())
}

/// The occupied cells (grid coordinates) and coding of the single plane of a map.
fn decoded_cells(bytes: &[u8]) -> (Vec<(usize, usize)>, CellCoding) {
    let mut out = (Vec::new(), CellCoding::Bitmap);
    wire::decode(bytes, |p| {
        if let Primitive::Plane(p) = p {
            let (a0, b0) = ((p.cells.a0 + 40) as usize, (p.cells.b0 + 40) as usize);
            p.cells.for_each_set(|i, j| {
                assert!(p.cells.is_set(i, j), "for_each_set and is_set agree");
                out.0.push((a0 + i, b0 + j));
            });
            out.1 = p.cells.coding;
        }
    })
    .unwrap();
    out
}

#[test]
fn plane_cells_take_the_shorter_coding_and_round_trip_exactly() {
    // A disc of radius 25 cells with a hole (an object standing on a floor): runs, several times smaller.
    let floor = |i: usize, j: usize| {
        let (x, y) = (i as f32 - 40.0, j as f32 - 38.0);
        let r2 = x * x + y * y;
        r2 <= 625.0 && !((-4.0..4.0).contains(&x) && (-6.0..3.0).contains(&y))
    };
    let (bytes, cells, bitmap_bytes) = plane_map(80, 80, floor);
    let (got, coding) = decoded_cells(&bytes);
    assert_eq!(coding, CellCoding::Edges);
    assert_eq!(got, cells);
    // The cropped 51 x 51 bitmap alone would be 326 bytes, its runs about 110; the whole map is below 100.
    assert!(bytes.len() < 100, "{} bytes for a disc (uncropped bitmap {bitmap_bytes})", bytes.len());
    // A band of 5 cells moving 9 cells per row: every row explicit as edges (22 bits), 2 bytes as runs.
    let (bytes, cells, _) = plane_map(80, 8, |i, j| (9 * j..9 * j + 5).contains(&i));
    assert_eq!(decoded_cells(&bytes), (cells, CellCoding::Runs));
    // A checkerboard: every run one cell long, the bitmap is shorter.
    let (bytes, cells, _) = plane_map(20, 12, |i, j| (i + j) % 2 == 0);
    let (got, coding) = decoded_cells(&bytes);
    assert_eq!((coding, got), (CellCoding::Bitmap, cells));
    // A single occupied cell, a full row, and an empty plane.
    for set in [|i: usize, j: usize| i == 7 && j == 9, |_: usize, j: usize| j == 3, |_: usize, _: usize| false] {
        let (bytes, cells, _) = plane_map(16, 16, set);
        assert_eq!(decoded_cells(&bytes).0, cells);
    }
}
