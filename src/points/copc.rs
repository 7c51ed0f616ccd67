//! COPC 1.0 (cloud-optimised point cloud) writing and the octree facts a reader by bounds
//! needs.
//!
//! A COPC file is a LAZ 1.4 file (point format 6, 7 or 8) whose point data is one LAZ chunk
//! per node of an octree, with variable-size chunks: the first VLR (at byte 375) holds the
//! octree's cube and the offset of the hierarchy, an EVLR after the points lists every node
//! (its key, the byte offset and size of its chunk and its number of points). A reader then
//! decodes only the nodes whose cube meets the box it wants.
//!
//! The octree ([`build_octree`]): the cube is the points' box made cubic about its centre
//! (half the longest side plus the largest scale step, so that every point lies strictly
//! inside). Each node lays a grid of [`NODE_GRID`]³ cells over its cube and keeps, in input
//! order, the first point of each cell; the points of cells already taken go down to the
//! child octant that holds them. A node of at most [`LEAF_POINTS`] points (or at level
//! [`MAX_LEVEL`]) keeps them all. So the spacing of level `l` is the cube's side / 128 / 2^l
//! (the info VLR's `spacing` is the root's), the rule of PDAL's `writers.copc` and untwine
//! (a fixed grid per node), with the first point of a cell instead of a random one, so the
//! file's bytes depend on the input alone. Nodes are written depth first (children in
//! octant order); a node's points keep their input order.
//!
//! The crates: `las` 0.11 reads COPC (`las::copc::CopcReader`, the tests' reader) but
//! cannot write it (its `CopcInfoVlr` has private fields and no constructor, its hierarchy
//! writer no way to build one); `laz` compresses the variable-size chunks
//! (`ParLasZipCompressor::compress_chunks`, in parallel, bytes independent of the threads).
//! The header, the two COPC records and the hierarchy page are written here by hand
//! (fixed little-endian layouts of the COPC 1.0 specification).

use super::las_header::{LasHeader, VLR_HEADER_SIZE};
use crate::error::{Error, Result};
use rayon::prelude::*;
use std::io::{Cursor, Seek, SeekFrom};
use std::path::Path;

/// Cells per side of a node's grid: a node keeps at most one point per cell.
pub const NODE_GRID: u32 = 128;
/// A node with at most this many points keeps them all (a leaf).
pub const LEAF_POINTS: usize = 50_000;
/// The deepest level: a node there keeps all its points.
pub const MAX_LEVEL: i32 = 20;
/// Size of a LAS 1.4 header, where the COPC info VLR starts.
const HEADER_SIZE: usize = 375;
/// Payload of the COPC info VLR.
const INFO_SIZE: usize = 160;
/// Size of an EVLR's header.
const EVLR_HEADER_SIZE: usize = 60;

/// What [`write_copc`] wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CopcWritten {
    /// Points written.
    pub points: u64,
    /// Octree nodes (LAZ chunks).
    pub nodes: usize,
    /// Levels of the octree (the deepest level plus one).
    pub levels: i32,
    /// The point format written (6, 7 or 8).
    pub point_format: u8,
}

/// The COPC point format for a LAS point format: 6 (no colour), 7 (RGB) or 8 (RGB and
/// near infrared); waveform packets (formats 4, 5, 9, 10) are dropped.
pub fn copc_format(point_format: u8) -> Option<u8> {
    match point_format {
        0 | 1 | 4 | 6 | 9 => Some(6),
        2 | 3 | 5 | 7 => Some(7),
        8 | 10 => Some(8),
        _ => None,
    }
}

/// One node of an octree: its key (level, x, y, z) and the indices of its points in input
/// order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Node {
    /// Level, then the node's position on that level's lattice.
    pub key: [i32; 4],
    /// Indices of its points, ascending.
    pub points: Vec<u32>,
}

/// The cube of an octree: its centre and half its side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cube {
    /// Centre.
    pub center: [f64; 3],
    /// Half the side.
    pub halfsize: f64,
}

impl Cube {
    /// The cube about the box `min`..`max`, enlarged by `pad` so every point is strictly
    /// inside.
    pub fn around(min: [f64; 3], max: [f64; 3], pad: f64) -> Cube {
        let center = std::array::from_fn(|k| (min[k] + max[k]) / 2.0);
        let half = (0..3).map(|k| (max[k] - min[k]) / 2.0).fold(0.0, f64::max);
        Cube {
            center,
            halfsize: half + pad.abs().max(f64::MIN_POSITIVE),
        }
    }

    /// The position of `p` in the cube, each coordinate in [0, 1).
    fn unit(&self, p: [f64; 3]) -> [f64; 3] {
        let side = 2.0 * self.halfsize;
        std::array::from_fn(|k| {
            let q = (p[k] - (self.center[k] - self.halfsize)) / side;
            q.clamp(0.0, 1.0 - f64::EPSILON)
        })
    }

    /// The x/y box of the node with `key`: (min x, min y, max x, max y).
    pub fn node_box(&self, key: [i32; 4]) -> [f64; 4] {
        let side = 2.0 * self.halfsize / f64::from(1u32 << key[0]);
        let x0 = self.center[0] - self.halfsize + side * f64::from(key[1]);
        let y0 = self.center[1] - self.halfsize + side * f64::from(key[2]);
        [x0, y0, x0 + side, y0 + side]
    }
}

/// The octree of `xyz` (see the module's documentation), nodes depth first.
pub fn build_octree(xyz: &[[f64; 3]], cube: &Cube) -> Vec<Node> {
    let unit: Vec<[f64; 3]> = xyz.par_iter().map(|&p| cube.unit(p)).collect();
    let all: Vec<u32> = (0..xyz.len() as u32).collect();
    let mut out = Vec::new();
    node(&unit, [0, 0, 0, 0], all, &mut out);
    out
}

/// The cell of a unit position on a lattice of `2^bits` per side.
fn cell(u: f64, bits: i32) -> i64 {
    let n = 1i64 << bits;
    ((u * n as f64) as i64).clamp(0, n - 1)
}

/// Appends the node `key` holding `idx` and, depth first, its children.
fn node(unit: &[[f64; 3]], key: [i32; 4], idx: Vec<u32>, out: &mut Vec<Node>) {
    if idx.len() <= LEAF_POINTS || key[0] >= MAX_LEVEL {
        out.push(Node { key, points: idx });
        return;
    }
    let g = NODE_GRID as i64;
    let bits = key[0] + NODE_GRID.trailing_zeros() as i32;
    let mut taken = vec![0u64; (g * g * g / 64) as usize];
    let mut keep = Vec::new();
    let mut child: [Vec<u32>; 8] = Default::default();
    for i in idx {
        let u = unit[i as usize];
        // The cell on this level's lattice, relative to the node's own grid.
        let c: [i64; 3] = std::array::from_fn(|k| cell(u[k], bits) - i64::from(key[k + 1]) * g);
        let at = ((c[2] * g + c[1]) * g + c[0]) as usize;
        if taken[at / 64] >> (at % 64) & 1 == 0 {
            taken[at / 64] |= 1 << (at % 64);
            keep.push(i);
        } else {
            let o = (c[0] >= g / 2) as usize
                | ((c[1] >= g / 2) as usize) << 1
                | ((c[2] >= g / 2) as usize) << 2;
            child[o].push(i);
        }
    }
    out.push(Node { key, points: keep });
    for (o, c) in child.into_iter().enumerate() {
        if c.is_empty() {
            continue;
        }
        let k = [
            key[0] + 1,
            2 * key[1] + (o & 1) as i32,
            2 * key[2] + (o >> 1 & 1) as i32,
            2 * key[3] + (o >> 2 & 1) as i32,
        ];
        node(unit, k, c, out);
    }
}

/// A VLR's 54-byte header and payload.
fn vlr_bytes(user: &str, record: u16, description: &str, data: &[u8]) -> Vec<u8> {
    let mut v = Vec::with_capacity(VLR_HEADER_SIZE as usize + data.len());
    v.extend_from_slice(&0u16.to_le_bytes());
    v.extend_from_slice(&padded::<16>(user));
    v.extend_from_slice(&record.to_le_bytes());
    v.extend_from_slice(&(data.len() as u16).to_le_bytes());
    v.extend_from_slice(&padded::<32>(description));
    v.extend_from_slice(data);
    v
}

fn padded<const N: usize>(s: &str) -> [u8; N] {
    let mut b = [0u8; N];
    let n = s.len().min(N);
    b[..n].copy_from_slice(&s.as_bytes()[..n]);
    b
}

fn las_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Usage(format!("{}: cannot write COPC: {e}", path.display()))
}

/// Writes `records` (whole records in `h`'s point format, `h` the input's header) to
/// `output` as a COPC 1.0 file: point format 6, 7 or 8 ([`copc_format`]) with every field
/// the target format holds mapped by the `las` crate's point conversion (intensity, returns,
/// class and its flags, scan direction and edge, scan angle (degrees to 0.006° steps), user
/// data, point source, GPS time, colour, near infrared, extra bytes) and the stored integer
/// coordinates unchanged (same scale and offset). The input's VLRs (its CRS, an extra-bytes
/// description) are copied; its EVLRs and waveform packets are not.
pub fn write_copc(h: &LasHeader, records: &[u8], output: &Path) -> Result<CopcWritten> {
    let len = h.record_length as usize;
    let n = records.len() / len.max(1);
    if n == 0 {
        return Err(Error::Usage(format!(
            "{}: no points to write as COPC",
            output.display()
        )));
    }
    if n > i32::MAX as usize {
        return Err(Error::Usage(format!(
            "{}: {n} points, more than a COPC file written here can hold (2^31 - 1)",
            output.display()
        )));
    }
    let (target, in_format, out_format) = formats(h, output)?;
    let extra = out_format.extra_bytes;
    let out_len = out_format.len() as usize;
    let converted = convert_records(h, records, &in_format, &out_format, output)?;
    let xyz: Vec<[f64; 3]> = converted
        .par_chunks_exact(out_len)
        .map(|r| {
            std::array::from_fn(|k| {
                let v = i32::from_le_bytes(r[4 * k..4 * k + 4].try_into().unwrap_or([0; 4]));
                h.scale[k] * f64::from(v) + h.offset[k]
            })
        })
        .collect();
    let (mut min, mut max) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &xyz {
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    let pad = h.scale.iter().fold(0.0f64, |a, s| a.max(s.abs()));
    let cube = Cube::around(min, max, pad);
    let nodes = build_octree(&xyz, &cube);
    drop(xyz);

    let ([gmin, gmax], by_return) = record_stats(&converted, out_len);

    let laz_vlr = laz::LazVlrBuilder::default()
        .with_point_format(target, extra)
        .map_err(|e| las_err(output, e))?
        .with_variable_chunk_size()
        .build();
    let mut laz_data = Vec::new();
    laz_vlr
        .write_to(&mut laz_data)
        .map_err(|e| las_err(output, e))?;
    let mut vlrs = vlr_bytes("copc", 1, "COPC info VLR", &[0u8; INFO_SIZE]);
    vlrs.extend(vlr_bytes("laszip encoded", 22204, "LASzip", &laz_data));
    let mut count_vlrs = 2u32;
    let mut wkt = false;
    for v in h.vlrs.iter().filter(|v| {
        !v.extended && !v.is_laszip() && !v.user_id.starts_with(b"copc\0") && v.data.len() <= 65535
    }) {
        wkt |= v.user_id.starts_with(b"LASF_Projection\0") && v.record_id == 2112;
        let raw = v.to_raw();
        raw.write_to(&mut vlrs).map_err(|e| las_err(output, e))?;
        count_vlrs += 1;
    }
    let offset_to_points = HEADER_SIZE + vlrs.len();

    let mut buf = Cursor::new(Vec::with_capacity(records.len() / 4));
    buf.get_mut().resize(offset_to_points, 0);
    buf.seek(SeekFrom::End(0)).map_err(|e| las_err(output, e))?;
    let chunks: Vec<Vec<u8>> = nodes
        .par_iter()
        .map(|nd| {
            let mut c = Vec::with_capacity(nd.points.len() * out_len);
            for &i in &nd.points {
                let i = i as usize;
                c.extend_from_slice(&converted[i * out_len..(i + 1) * out_len]);
            }
            c
        })
        .collect();
    drop(converted);
    let mut comp =
        laz::ParLasZipCompressor::new(buf, laz_vlr.clone()).map_err(|e| las_err(output, e))?;
    comp.compress_chunks(chunks.par_iter())
        .map_err(|e| las_err(output, e))?;
    comp.done().map_err(|e| las_err(output, e))?;
    drop(chunks);
    let mut bytes = comp.into_inner().into_inner();
    // The chunks' sizes, read back from the table the compressor wrote.
    let table = {
        let mut c = Cursor::new(&bytes[..]);
        c.seek(SeekFrom::Start(offset_to_points as u64))
            .map_err(|e| las_err(output, e))?;
        laz::laszip::ChunkTable::read_from(&mut c, &laz_vlr).map_err(|e| las_err(output, e))?
    };
    let page = hierarchy_page(&nodes, table.as_ref(), offset_to_points as u64 + 8);
    let evlr_at = bytes.len() as u64;
    bytes.extend_from_slice(&0u16.to_le_bytes());
    bytes.extend_from_slice(&padded::<16>("copc"));
    bytes.extend_from_slice(&1000u16.to_le_bytes());
    bytes.extend_from_slice(&(page.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&padded::<32>("EPT hierarchy"));
    bytes.extend_from_slice(&page);

    let info = info_payload(
        &cube,
        evlr_at + EVLR_HEADER_SIZE as u64,
        page.len() as u64,
        [gmin, gmax],
    );
    vlrs[VLR_HEADER_SIZE as usize..VLR_HEADER_SIZE as usize + INFO_SIZE].copy_from_slice(&info);

    let mut raw = h.raw.clone();
    raw.version = las::Version::new(1, 4);
    raw.global_encoding = (h.raw.global_encoding & 1) | if wkt { 16 } else { 0 };
    raw.system_identifier = padded::<32>("terratile");
    raw.generating_software = padded::<32>(&format!("terratile {}", env!("CARGO_PKG_VERSION")));
    raw.header_size = HEADER_SIZE as u16;
    raw.offset_to_point_data = offset_to_points as u32;
    raw.number_of_variable_length_records = count_vlrs;
    raw.point_data_record_format = target | 0x80;
    raw.point_data_record_length = out_len as u16;
    raw.number_of_point_records = 0;
    raw.number_of_points_by_return = [0; 5];
    (raw.min_x, raw.min_y, raw.min_z) = (min[0], min[1], min[2]);
    (raw.max_x, raw.max_y, raw.max_z) = (max[0], max[1], max[2]);
    raw.start_of_waveform_data_packet_record = Some(0);
    raw.evlr = Some(las::raw::header::Evlr {
        start_of_first_evlr: evlr_at,
        number_of_evlrs: 1,
    });
    raw.large_file = Some(las::raw::header::LargeFile {
        number_of_point_records: n as u64,
        number_of_points_by_return: by_return,
    });
    raw.padding = Vec::new();
    let head = header_bytes(&raw, output)?;
    bytes[..HEADER_SIZE].copy_from_slice(&head);
    bytes[HEADER_SIZE..offset_to_points].copy_from_slice(&vlrs);
    crate::fsutil::write_bytes_atomic(output, &bytes)?;
    Ok(CopcWritten {
        points: n as u64,
        nodes: nodes.len(),
        levels: nodes.iter().map(|nd| nd.key[0]).max().unwrap_or(0) + 1,
        point_format: target,
    })
}

/// A LAS 1.4 header's 375 bytes.
fn header_bytes(raw: &las::raw::Header, output: &Path) -> Result<Vec<u8>> {
    let mut head = Vec::with_capacity(HEADER_SIZE);
    raw.write_to(&mut head).map_err(|e| las_err(output, e))?;
    if head.len() != HEADER_SIZE {
        return Err(Error::Internal(format!(
            "a LAS 1.4 header of {} bytes",
            head.len()
        )));
    }
    Ok(head)
}

/// The info VLR's payload (COPC 1.0: centre, half size, spacing, root page, GPS range).
fn info_payload(cube: &Cube, root_at: u64, root_size: u64, gps: [f64; 2]) -> Vec<u8> {
    let mut info = Vec::with_capacity(INFO_SIZE);
    for v in [
        cube.center[0],
        cube.center[1],
        cube.center[2],
        cube.halfsize,
    ] {
        info.extend_from_slice(&v.to_le_bytes());
    }
    info.extend_from_slice(&(2.0 * cube.halfsize / f64::from(NODE_GRID)).to_le_bytes());
    info.extend_from_slice(&root_at.to_le_bytes());
    info.extend_from_slice(&root_size.to_le_bytes());
    info.extend_from_slice(&gps[0].to_le_bytes());
    info.extend_from_slice(&gps[1].to_le_bytes());
    info.resize(INFO_SIZE, 0);
    info
}

/// The COPC point format for `h`'s, and the input's and the output's `las` formats (with the
/// input's extra bytes).
fn formats(h: &LasHeader, output: &Path) -> Result<(u8, las::point::Format, las::point::Format)> {
    let len = h.record_length as usize;
    let target = copc_format(h.point_format).ok_or_else(|| {
        Error::Usage(format!(
            "{}: point format {} has no COPC equivalent",
            output.display(),
            h.point_format
        ))
    })?;
    let mut in_format = las::point::Format::new(h.point_format).map_err(|e| las_err(output, e))?;
    let base = in_format.len() as usize;
    if len < base {
        return Err(Error::Usage(format!(
            "{}: records of {len} bytes are shorter than point format {} ({base})",
            output.display(),
            h.point_format
        )));
    }
    let extra = (len - base) as u16;
    in_format.extra_bytes = extra;
    let mut out_format = las::point::Format::new(target).map_err(|e| las_err(output, e))?;
    out_format.extra_bytes = extra;

    Ok((target, in_format, out_format))
}

/// Each record in the target format.
fn convert_records(
    h: &LasHeader,
    records: &[u8],
    in_format: &las::point::Format,
    out_format: &las::point::Format,
    output: &Path,
) -> Result<Vec<u8>> {
    let (len, out_len) = (h.record_length as usize, out_format.len() as usize);
    let n = records.len() / len;
    let t = |k: usize| las::Transform {
        scale: h.scale[k],
        offset: h.offset[k],
    };
    let transforms = las::Vector {
        x: t(0),
        y: t(1),
        z: t(2),
    };
    // Each record in the target format, the stored integers copied as they are. The `las`
    // point conversion allocates a point's extra bytes: `convert` is not a hot path.
    let mut converted = vec![0u8; n * out_len];
    converted
        .par_chunks_mut(out_len)
        .zip(records.par_chunks_exact(len))
        .try_for_each(|(o, r)| -> std::result::Result<(), las::Error> {
            let raw = las::raw::Point::read_from(r, in_format)?;
            let (x, y, z) = (raw.x, raw.y, raw.z);
            let mut back = las::Point::new(raw, &transforms).into_raw(&transforms)?;
            (back.x, back.y, back.z) = (x, y, z);
            back.write_to(&mut &mut o[..], out_format)
        })
        .map_err(|e| las_err(output, e))?;
    Ok(converted)
}

/// The records' GPS time range (every COPC format has it, at byte 22) and points by return.
fn record_stats(converted: &[u8], out_len: usize) -> ([f64; 2], [u64; 15]) {
    let (mut gmin, mut gmax) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut by_return = [0u64; 15];
    for r in converted.chunks_exact(out_len) {
        let g = f64::from_le_bytes(r[22..30].try_into().unwrap_or([0; 8]));
        gmin = gmin.min(g);
        gmax = gmax.max(g);
        let ret = r[14] & 0x0F;
        if (1..=15).contains(&ret) {
            by_return[ret as usize - 1] += 1;
        }
    }

    ([gmin, gmax], by_return)
}

/// The hierarchy page: one 32-byte entry per node, its chunk's offset from the chunks' sizes
/// in `table`, the first chunk at `at`.
fn hierarchy_page(nodes: &[Node], table: &[laz::laszip::ChunkTableEntry], mut at: u64) -> Vec<u8> {
    let mut page = Vec::with_capacity(nodes.len() * 32);
    for (nd, e) in nodes.iter().zip(table.as_ref()) {
        for k in nd.key {
            page.extend_from_slice(&k.to_le_bytes());
        }
        page.extend_from_slice(&at.to_le_bytes());
        page.extend_from_slice(&(e.byte_count as i32).to_le_bytes());
        page.extend_from_slice(&(nd.points.len() as i32).to_le_bytes());
        at += e.byte_count;
    }
    page
}

/// One octree node's LAZ chunk in a COPC file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct NodeChunk {
    /// Level, x, y, z.
    pub key: [i32; 4],
    /// Byte offset of the chunk.
    pub offset: u64,
    /// Compressed bytes.
    pub bytes: u64,
    /// Points in the chunk.
    pub points: u64,
}

/// The octree of a COPC file as its header and hierarchy give it.
#[derive(Debug, Clone, PartialEq)]
pub struct CopcLayout {
    /// The cube.
    pub cube: Cube,
    /// The nodes with points, in file order: their chunks follow each other from the first
    /// point byte, so the points of node `k` are the records after those of nodes `..k`.
    pub nodes: Vec<NodeChunk>,
}

/// True when the header's first VLR is a COPC info VLR.
pub fn is_copc(h: &LasHeader) -> bool {
    h.vlrs
        .first()
        .is_some_and(|v| !v.extended && v.user_id.starts_with(b"copc\0") && v.record_id == 1)
}

fn le_u64(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap_or([0; 8]))
}

fn le_i32(b: &[u8], at: usize) -> i32 {
    i32::from_le_bytes(b[at..at + 4].try_into().unwrap_or([0; 4]))
}

/// The octree of the COPC file `bytes` (header `h`); `None` when it is not COPC or its
/// chunks do not follow each other in the file (then it is read whole, as LAZ). A hierarchy
/// that lies outside the file, a node whose chunk does, or node counts that disagree with
/// the header are refused with one line naming the file and the byte.
pub fn layout(path: &Path, bytes: &[u8], h: &LasHeader) -> Result<Option<CopcLayout>> {
    if !is_copc(h) || !h.compressed || h.point_format < 6 {
        return Ok(None);
    }
    let bad = |at: u64, m: String| Error::format(path, at, format!("COPC: {m}"));
    let info = &h.vlrs[0].data;
    if info.len() < INFO_SIZE {
        return Err(bad(
            HEADER_SIZE as u64,
            format!("info VLR of {} bytes, not {INFO_SIZE}", info.len()),
        ));
    }
    let f = |k: usize| f64::from_le_bytes(info[8 * k..8 * k + 8].try_into().unwrap_or([0; 8]));
    let cube = Cube {
        center: [f(0), f(1), f(2)],
        halfsize: f(3),
    };
    if !(cube.halfsize > 0.0 && cube.halfsize.is_finite()) {
        return Err(bad(
            HEADER_SIZE as u64,
            "the octree's half size is not positive".into(),
        ));
    }
    let (root_at, root_size) = (le_u64(info, 40), le_u64(info, 48));
    let len = bytes.len() as u64;
    let first = h.offset_to_points + 8;
    let mut nodes = Vec::new();
    let mut pages = vec![(root_at, root_size)];
    let mut seen = 0usize;
    while let Some((at, size)) = pages.pop() {
        seen += 1;
        if size % 32 != 0 || at.checked_add(size).is_none_or(|e| e > len) || seen > 1 << 20 {
            return Err(bad(
                at,
                format!("hierarchy page of {size} bytes at byte {at} lies outside the file ({len} bytes)"),
            ));
        }
        for e in 0..(size / 32) as usize {
            let o = at as usize + 32 * e;
            let key = [
                le_i32(bytes, o),
                le_i32(bytes, o + 4),
                le_i32(bytes, o + 8),
                le_i32(bytes, o + 12),
            ];
            let (offset, size, count) = (
                le_u64(bytes, o + 16),
                le_i32(bytes, o + 24),
                le_i32(bytes, o + 28),
            );
            if count == -1 {
                pages.push((offset, size.max(0) as u64));
            } else if count > 0 {
                let end = offset.checked_add(size.max(0) as u64);
                if size <= 0 || offset < first || end.is_none_or(|e| e > len) {
                    return Err(bad(
                        o as u64,
                        format!(
                            "node {}-{}-{}-{}: chunk of {size} bytes at byte {offset} lies outside the point data (bytes {first} to {len})",
                            key[0], key[1], key[2], key[3]
                        ),
                    ));
                }
                nodes.push(NodeChunk {
                    key,
                    offset,
                    bytes: size as u64,
                    points: count as u64,
                });
            }
        }
    }
    nodes.sort_by_key(|n| n.offset);
    let total: u64 = nodes.iter().map(|n| n.points).sum();
    if total != h.point_count {
        return Err(bad(
            root_at,
            format!(
                "the hierarchy's nodes hold {total} points, the header {}",
                h.point_count
            ),
        ));
    }
    let mut next = first;
    for n in &nodes {
        if n.offset != next {
            return Ok(None);
        }
        next += n.bytes;
    }
    Ok(Some(CopcLayout { cube, nodes }))
}

/// Decodes the chunk of `node` (a node of [`layout`]'s) into `cloud` (cleared first) with
/// the record decoder of every LAS reader, the class filter of `opts` and at most `cap`
/// points kept; returns the points kept.
pub(crate) fn decode_node(
    path: &Path,
    bytes: &[u8],
    h: &LasHeader,
    node: &NodeChunk,
    opts: &super::ReadOptions,
    cap: Option<u64>,
    cloud: &mut super::PointCloud,
) -> Result<u64> {
    let vlr = h
        .laszip_vlr()
        .ok_or_else(|| Error::format(path, 0, "COPC without a LASzip VLR"))?;
    let laz_vlr = laz::LazVlr::read_from(vlr.data.as_slice())
        .map_err(|e| Error::format(path, 0, format!("unreadable LASzip VLR: {e}")))?;
    let len = h.record_length as usize;
    if laz_vlr.items_size() as usize != len {
        return Err(Error::format(
            path,
            0,
            "the record length disagrees with the LASzip items",
        ));
    }
    let mut buf = vec![0u8; node.points as usize * len];
    let at = node.offset;
    let chunk = &bytes[at as usize..(at + node.bytes) as usize];
    // A corrupt chunk can make the decompressor panic: that is a format error, not an abort.
    let done = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        use laz::record::RecordDecompressor;
        let mut d = laz::record::LayeredPointRecordDecompressor::new(Cursor::new(chunk));
        d.set_fields_from(laz_vlr.items())
            .map_err(|e| e.to_string())?;
        d.decompress_many(&mut buf).map_err(|e| e.to_string())
    }));
    match done {
        Ok(Ok(())) => {}
        Ok(Err(e)) => {
            return Err(Error::format(
                path,
                at,
                format!("corrupt COPC node {:?}: {e}", node.key),
            ))
        }
        Err(_) => {
            return Err(Error::format(
                path,
                at,
                format!("corrupt COPC node {:?}: the decompressor failed", node.key),
            ))
        }
    }
    let layout = super::las_records::Layout {
        len,
        extended: h.point_format >= 6,
        scale: h.scale,
        offset: h.offset,
        columns: opts.columns,
    };
    // Emptied, its buffers kept for the next node.
    cloud.truncate(0);
    Ok(super::las_records::decode(&buf, &layout, &opts.classes, cap, cloud).0 as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The octree's invariants on a random cloud: every point in exactly one node, a node's
    /// points inside its cube, at most one point per cell in inner nodes, children one level
    /// down under their parent.
    #[test]
    fn octree_partitions_the_points_by_cells() {
        let mut rng = crate::rng::SplitMix64::new(7);
        let xyz: Vec<[f64; 3]> = (0..150_000)
            .map(|_| [rng.unit() * 1000.0, rng.unit() * 500.0, rng.unit() * 20.0])
            .collect();
        let cube = Cube::around([0.0; 3], [1000.0, 500.0, 20.0], 0.01);
        let nodes = build_octree(&xyz, &cube);
        assert!(nodes.len() > 1);
        let mut seen = vec![0u8; xyz.len()];
        let keys: std::collections::HashSet<[i32; 4]> = nodes.iter().map(|n| n.key).collect();
        assert_eq!(keys.len(), nodes.len(), "keys are unique");
        for nd in &nodes {
            assert!(nd.points.windows(2).all(|w| w[0] < w[1]), "input order");
            let [x0, y0, x1, y1] = cube.node_box(nd.key);
            let mut cells = std::collections::HashSet::new();
            let bits = nd.key[0] + 7;
            for &i in &nd.points {
                seen[i as usize] += 1;
                let p = xyz[i as usize];
                assert!(p[0] >= x0 && p[0] <= x1 && p[1] >= y0 && p[1] <= y1);
                let u = cube.unit(p);
                cells.insert([cell(u[0], bits), cell(u[1], bits), cell(u[2], bits)]);
            }
            if nd.key[0] > 0 {
                let k = nd.key;
                assert!(keys.contains(&[k[0] - 1, k[1] >> 1, k[2] >> 1, k[3] >> 1]));
            }
            let leaf = !nodes.iter().any(|c| {
                c.key[0] == nd.key[0] + 1
                    && c.key[1] >> 1 == nd.key[1]
                    && c.key[2] >> 1 == nd.key[2]
                    && c.key[3] >> 1 == nd.key[3]
            });
            if !leaf {
                assert_eq!(cells.len(), nd.points.len(), "one point per cell");
            }
        }
        assert!(seen.iter().all(|&s| s == 1));
    }
}
