//! Generators of the bad point-cloud inputs of issue 14 (small files built in memory, never
//! copies of the shared data), for the regression tests and the mutation fuzzers.

/// A hand-built LAS 1.4 file, point format 0: `points` records, then one EVLR of 15 bytes.
/// `evlr_len` and `evlr_start` override the EVLR's length field and the header's offset to
/// the first EVLR; `scale` and `offset` apply to all three axes.
pub fn las14(
    points: usize,
    evlr_len: Option<u64>,
    evlr_start: Option<u64>,
    scale: f64,
    offset: f64,
) -> Vec<u8> {
    let header_size = 375usize;
    let mut h = vec![0u8; header_size];
    h[0..4].copy_from_slice(b"LASF");
    h[24] = 1;
    h[25] = 4;
    h[94..96].copy_from_slice(&(header_size as u16).to_le_bytes());
    h[96..100].copy_from_slice(&(header_size as u32).to_le_bytes());
    h[104] = 0;
    h[105..107].copy_from_slice(&20u16.to_le_bytes());
    h[107..111].copy_from_slice(&(points as u32).to_le_bytes());
    for k in 0..3 {
        h[131 + 8 * k..139 + 8 * k].copy_from_slice(&scale.to_le_bytes());
        h[155 + 8 * k..163 + 8 * k].copy_from_slice(&offset.to_le_bytes());
    }
    // max x, min x, max y, min y, max z, min z
    for (k, v) in [10.0f64, 0.0, 5.0, 0.0, 1.0, 0.0].iter().enumerate() {
        h[179 + 8 * k..187 + 8 * k].copy_from_slice(&v.to_le_bytes());
    }
    let start = (header_size + 20 * points) as u64;
    h[235..243].copy_from_slice(&evlr_start.unwrap_or(start).to_le_bytes());
    h[243..247].copy_from_slice(&1u32.to_le_bytes());
    h[247..255].copy_from_slice(&(points as u64).to_le_bytes());
    let mut out = h;
    for i in 0..points as i32 {
        out.extend_from_slice(&(i * 100).to_le_bytes());
        out.extend_from_slice(&((i * 37) % 500).to_le_bytes());
        out.extend_from_slice(&(i * 13).to_le_bytes());
        out.extend_from_slice(&[0, 0, 0x09, 2, 0, 0, 0, 0]);
    }
    let data = b"an evlr payload";
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&[b't'; 16]);
    out.extend_from_slice(&1u16.to_le_bytes());
    out.extend_from_slice(&evlr_len.unwrap_or(data.len() as u64).to_le_bytes());
    out.extend_from_slice(&[b'd'; 32]);
    out.extend_from_slice(data);
    out
}

/// A LAS (or LAZ, `compressed`) of `n` points in point format 3 (GPS time and colour), with
/// `outliers` points far above the rest: a 1 m grid of a gentle slope.
pub fn las_format3(n: usize, outliers: usize, compressed: bool) -> Vec<u8> {
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(3).unwrap();
    b.point_format.is_compressed = compressed;
    let header = b.into_header().unwrap();
    let mut w = las::Writer::new(std::io::Cursor::new(Vec::new()), header).unwrap();
    let side = (n as f64).sqrt().ceil() as usize;
    for i in 0..n + outliers {
        let (x, y) = ((i % side) as f64, ((i / side) % side) as f64);
        let z = if i >= n {
            500.0 + 97.0 * (i - n) as f64
        } else {
            0.05 * x + 0.02 * y
        };
        let p = las::Point {
            x,
            y,
            z,
            intensity: (i % 1000) as u16,
            return_number: 1,
            number_of_returns: 1,
            classification: las::point::Classification::Ground,
            gps_time: Some(1000.0 + i as f64),
            color: Some(las::Color::new(i as u16, 2 * i as u16, 3 * i as u16)),
            ..Default::default()
        };
        w.write_point(p).unwrap();
    }
    w.into_inner().unwrap().into_inner()
}

/// Overwrites `len` bytes at `at`.
pub fn patch(bytes: &mut [u8], at: usize, value: &[u8]) {
    bytes[at..at + value.len()].copy_from_slice(value);
}

/// A LAZ whose legacy point count says `count`.
pub fn laz_with_count(count: u32) -> Vec<u8> {
    let mut b = las_format3(3000, 0, true);
    patch(&mut b, 107, &count.to_le_bytes());
    b
}

/// A LAZ whose chunk table entries are garbage (huge byte counts).
pub fn laz_junk_chunk_table() -> Vec<u8> {
    let mut b = las_format3(3000, 0, true);
    let at = u32::from_le_bytes(b[96..100].try_into().unwrap()) as usize;
    let table = i64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize;
    let end = b.len();
    for x in &mut b[table + 8..end] {
        *x = 0xFF;
    }
    b
}

/// `n` points of XYZ text on a 40-wide grid.
pub fn xyz_grid(n: usize) -> String {
    (0..n)
        .map(|i| format!("{} {} {}\n", i % 40, i / 40, (i * 7) % 13))
        .collect()
}
