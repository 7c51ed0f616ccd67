//! The LAS public header block and VLRs: parsed with `las::raw`, then validated field by field
//! so that every complaint names the byte offset of the field at fault (ASPRS LAS 1.4 R15,
//! Table 3 gives the offsets).

use super::crs::Crs;
use crate::error::{Error, Result};
use std::path::Path;

/// Byte offsets of header fields (identical for LAS 1.0–1.4).
pub(crate) mod off {
    pub const VERSION_MAJOR: u64 = 24;
    pub const VERSION_MINOR: u64 = 25;
    pub const HEADER_SIZE: u64 = 94;
    pub const OFFSET_TO_POINTS: u64 = 96;
    pub const POINT_FORMAT: u64 = 104;
    pub const RECORD_LENGTH: u64 = 105;
    pub const COUNT_LEGACY: u64 = 107;
    pub const SCALE: u64 = 131;
    pub const OFFSET: u64 = 155;
    pub const START_OF_EVLRS: u64 = 235;
    pub const COUNT_14: u64 = 247;
}

/// Size of the LAS 1.0–1.2 public header block, the smallest a LAS file can have (LAS 1.4
/// R15, Table 3; `las::Version::header_size`).
const MIN_HEADER_SIZE: u64 = 227;

/// Size of a VLR's header before its payload (las-rs' `REGULAR_HEADER_SIZE`).
pub(crate) const VLR_HEADER_SIZE: u64 = 54;

/// Size of an EVLR's header before its payload (las-rs' `EXTENDED_HEADER_SIZE`).
const EVLR_HEADER_SIZE: u64 = 60;

/// Offset of the payload length inside an EVLR's header (an 8-byte unsigned field).
const EVLR_DATA_LENGTH: usize = 20;

/// Largest coordinate magnitude a LAS header may produce: far beyond any survey, far below
/// where f32 heights (3.4e38) or squared distances overflow.
pub(crate) const MAX_COORDINATE: f64 = 1e30;

/// Smallest record length of each point format 0–10 (LAS 1.4 R15, Tables 7–17).
pub(crate) const MIN_RECORD_LEN: [u16; 11] = [20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67];

/// LASzip's VLR: user id "laszip encoded", record 22204.
const LASZIP_USER: &[u8] = b"laszip encoded";
const LASZIP_RECORD: u16 = 22204;

/// What terratile needs from a LAS header, validated.
#[derive(Debug, Clone)]
pub struct LasHeader {
    /// The raw header as `las` parsed it.
    pub raw: las::raw::Header,
    /// Version (major, minor).
    pub version: (u8, u8),
    /// Point format 0–10 (compression bits removed).
    pub point_format: u8,
    /// True for LASzip-compressed point data.
    pub compressed: bool,
    /// Bytes per point record (uncompressed).
    pub record_length: u16,
    /// Number of point records the header promises.
    pub point_count: u64,
    /// Where point data starts.
    pub offset_to_points: u64,
    /// Scale factors.
    pub scale: [f64; 3],
    /// Offsets.
    pub offset: [f64; 3],
    /// The VLRs and EVLRs.
    pub vlrs: Vec<Vlr>,
    /// The CRS found in the VLRs.
    pub crs: Option<Crs>,
}

/// A variable-length record (or an extended one, from after the point data).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Vlr {
    /// User id, NUL-padded.
    pub user_id: [u8; 16],
    /// Record id.
    pub record_id: u16,
    /// Description, NUL-padded.
    pub description: [u8; 32],
    /// Payload.
    pub data: Vec<u8>,
    /// True for an EVLR.
    pub extended: bool,
}

impl Vlr {
    fn from_raw(v: las::raw::Vlr, extended: bool) -> Vlr {
        Vlr {
            user_id: v.user_id,
            record_id: v.record_id,
            description: v.description,
            data: v.data,
            extended,
        }
    }

    /// Back to `las`'s raw form (as a plain VLR).
    pub fn to_raw(&self) -> las::raw::Vlr {
        las::raw::Vlr {
            reserved: 0,
            user_id: self.user_id,
            record_id: self.record_id,
            record_length_after_header: las::raw::vlr::RecordLength::Vlr(self.data.len() as u16),
            description: self.description,
            data: self.data.clone(),
        }
    }

    /// True for LASzip's VLR.
    pub fn is_laszip(&self) -> bool {
        self.record_id == LASZIP_RECORD && self.user_id.starts_with(LASZIP_USER)
    }
}

/// True if a LAS header's point format byte carries LASzip's compression bits.
pub(crate) fn looks_compressed(head: &[u8]) -> bool {
    head.get(off::POINT_FORMAT as usize)
        .is_some_and(|&pf| pf & 0xC0 != 0)
}

/// The checks that need no parsed header: the file is not empty, starts with `LASF`, is long
/// enough for the smallest header and for its version's header, and has a version terratile
/// reads. Returns the version (major, minor).
fn check_start(path: &Path, bytes: &[u8]) -> Result<(u8, u8)> {
    let len = bytes.len() as u64;
    let truncated = |need: u64, what: &str| {
        Error::format(
            path,
            len,
            format!("truncated header: the file ends after {len} bytes, {what} needs {need}"),
        )
    };
    if len == 0 {
        return Err(Error::format(path, 0, "empty file"));
    }
    if !bytes.starts_with(b"LASF") {
        return Err(Error::format(
            path,
            0,
            "not a LAS file: signature is not LASF",
        ));
    }
    if len < MIN_HEADER_SIZE {
        return Err(truncated(MIN_HEADER_SIZE, "a LAS header"));
    }
    let (major, minor) = (
        bytes[off::VERSION_MAJOR as usize],
        bytes[off::VERSION_MINOR as usize],
    );
    if major != 1 || minor > 4 {
        return Err(Error::format(
            path,
            if major != 1 {
                off::VERSION_MAJOR
            } else {
                off::VERSION_MINOR
            },
            format!("unsupported LAS version {major}.{minor} (terratile reads 1.0 to 1.4)"),
        ));
    }
    let need = las::Version::new(major, minor).header_size() as u64;
    if len < need {
        return Err(truncated(need, &format!("a LAS {major}.{minor} header")));
    }
    Ok((major, minor))
}

/// The point format (0–10, allowed by the version) and its record length. Returns the format
/// without LASzip's compression bits, and whether those bits were set.
fn check_point_format(
    path: &Path,
    raw: &las::raw::Header,
    (major, minor): (u8, u8),
) -> Result<(u8, bool)> {
    let pf_byte = raw.point_data_record_format;
    let compressed = pf_byte & 0xC0 != 0;
    let point_format = pf_byte & 0x3F;
    if point_format > 10 {
        return Err(Error::format(
            path,
            off::POINT_FORMAT,
            format!("unsupported point data record format {point_format} (LAS defines 0 to 10)"),
        ));
    }
    if point_format >= 6 && minor < 4 {
        return Err(Error::format(
            path,
            off::POINT_FORMAT,
            format!("point format {point_format} needs LAS 1.4, the file says {major}.{minor}"),
        ));
    }
    let record_length = raw.point_data_record_length;
    let min_len = MIN_RECORD_LEN[point_format as usize];
    if record_length < min_len {
        return Err(Error::format(
            path,
            off::RECORD_LENGTH,
            format!(
                "point record length {record_length} is too short for point format {point_format} (at least {min_len} bytes)"
            ),
        ));
    }
    Ok((point_format, compressed))
}

/// The scale factors and offsets: finite, scales non-zero, and no record able to hold a
/// coordinate beyond [`MAX_COORDINATE`]. Returns (scale, offset).
fn check_scale_offset(path: &Path, raw: &las::raw::Header) -> Result<([f64; 3], [f64; 3])> {
    // The error of axis k's field in the run of three that starts at `first`.
    let axis_error =
        |first: u64, k: usize, message: String| Error::format(path, first + 8 * k as u64, message);
    let scale = [raw.x_scale_factor, raw.y_scale_factor, raw.z_scale_factor];
    for (k, s) in scale.iter().enumerate() {
        if *s == 0.0 || !s.is_finite() {
            return Err(axis_error(
                off::SCALE,
                k,
                format!(
                    "{} scale factor is {s}; it must be finite and non-zero",
                    ["x", "y", "z"][k]
                ),
            ));
        }
    }
    let offset = [raw.x_offset, raw.y_offset, raw.z_offset];
    for (k, o) in offset.iter().enumerate() {
        if !o.is_finite() {
            return Err(axis_error(
                off::OFFSET,
                k,
                format!("{} offset is {o}", ["x", "y", "z"][k]),
            ));
        }
    }
    // The largest coordinate a record can hold is |scale| · 2^31 + |offset|: reject the
    // header when that passes MAX_COORDINATE (coordinates would overflow to ±inf in the
    // stages' arithmetic and heights to inf as f32, then turn into NaN downstream).
    for k in 0..3 {
        let axis = ["x", "y", "z"][k];
        let reach = scale[k].abs() * 2147483648.0;
        if reach.is_nan() || reach > MAX_COORDINATE {
            return Err(axis_error(
                off::SCALE,
                k,
                format!(
                    "{axis} scale factor {:e} puts coordinates beyond ±{MAX_COORDINATE:e} (scale × 2^31 = {reach:e})",
                    scale[k]
                ),
            ));
        }
        if reach + offset[k].abs() > MAX_COORDINATE {
            return Err(axis_error(
                off::OFFSET,
                k,
                format!(
                    "{axis} offset {:e} puts coordinates beyond ±{MAX_COORDINATE:e}",
                    offset[k]
                ),
            ));
        }
    }
    Ok((scale, offset))
}

/// The number of point records: the legacy 32-bit field, or LAS 1.4's 64-bit one when the
/// legacy field is 0; the two must agree when both are set.
fn check_point_count(path: &Path, raw: &las::raw::Header) -> Result<u64> {
    let legacy = raw.number_of_point_records as u64;
    match raw.large_file {
        Some(lf) if legacy == 0 => Ok(lf.number_of_point_records),
        Some(lf) if lf.number_of_point_records != 0 && lf.number_of_point_records != legacy => {
            Err(Error::format(
                path,
                off::COUNT_14,
                format!(
                    "point counts disagree: legacy field says {legacy}, LAS 1.4 field says {}",
                    lf.number_of_point_records
                ),
            ))
        }
        _ => Ok(legacy),
    }
}

/// The offset to the point data: after the header, not past the end of the file (`len`
/// bytes).
fn check_offset_to_points(path: &Path, raw: &las::raw::Header, len: u64) -> Result<u64> {
    let offset_to_points = raw.offset_to_point_data as u64;
    if offset_to_points < raw.header_size as u64 {
        return Err(Error::format(
            path,
            off::OFFSET_TO_POINTS,
            format!(
                "offset to point data {offset_to_points} lies inside the {}-byte header",
                raw.header_size
            ),
        ));
    }
    if offset_to_points > len {
        return Err(Error::format(
            path,
            off::OFFSET_TO_POINTS,
            format!(
                "offset to point data {offset_to_points} is past the end of the file ({len} bytes)"
            ),
        ));
    }
    Ok(offset_to_points)
}

/// The VLRs between the header and the point data, each required to fit before the point data.
fn read_vlrs(
    path: &Path,
    bytes: &[u8],
    raw: &las::raw::Header,
    offset_to_points: u64,
) -> Result<Vec<Vlr>> {
    let mut vlrs = Vec::new();
    let mut at = raw.header_size as u64;
    for k in 0..raw.number_of_variable_length_records {
        if at + VLR_HEADER_SIZE > offset_to_points {
            return Err(Error::format(
                path,
                at,
                format!(
                    "VLR {k} of {} does not fit before the point data at byte {offset_to_points}",
                    raw.number_of_variable_length_records
                ),
            ));
        }
        let vlr = las::raw::Vlr::read_from(&bytes[at as usize..offset_to_points as usize], false)
            .map_err(|_| {
            Error::format(
                path,
                at,
                format!("VLR {k} runs past the start of the point data"),
            )
        })?;
        at += VLR_HEADER_SIZE + vlr.data.len() as u64;
        vlrs.push(Vlr::from_raw(vlr, false));
    }
    Ok(vlrs)
}

/// The EVLRs (LAS 1.4) after the point data, appended to `vlrs`. An EVLR table that points
/// into the header or the VLRs, or whose records run past the end of the file, is an error at
/// the field at fault: it may hold the CRS, and silently losing the CRS would change the
/// units. Every length is checked against the bytes present before anything is allocated.
fn read_evlrs(
    path: &Path,
    bytes: &[u8],
    raw: &las::raw::Header,
    offset_to_points: u64,
    vlrs: &mut Vec<Vlr>,
) -> Result<()> {
    let Some(evlr) = raw.evlr else {
        return Ok(());
    };
    let len = bytes.len() as u64;
    let count = evlr.number_of_evlrs;
    let mut at = evlr.start_of_first_evlr;
    if count > 0 && at != 0 && at < offset_to_points {
        return Err(Error::format(
            path,
            off::START_OF_EVLRS,
            format!("first EVLR offset {at} lies before the point data (byte {offset_to_points})"),
        ));
    }
    for k in 0..if at == 0 { 0 } else { count } {
        if at.checked_add(EVLR_HEADER_SIZE).is_none_or(|end| end > len) {
            return Err(Error::format(
                path,
                if k == 0 { off::START_OF_EVLRS } else { at },
                format!(
                    "EVLR {k} of {count} at byte {at} runs past the end of the file ({len} bytes)"
                ),
            ));
        }
        let length_at = at as usize + EVLR_DATA_LENGTH;
        let data_len =
            u64::from_le_bytes(bytes[length_at..length_at + 8].try_into().unwrap_or([0; 8]));
        if data_len > len - (at + EVLR_HEADER_SIZE) {
            return Err(Error::format(
                path,
                length_at as u64,
                format!(
                    "EVLR {k} of {count} claims {data_len} bytes of data, the file holds {} after its header",
                    len - (at + EVLR_HEADER_SIZE)
                ),
            ));
        }
        let v = las::raw::Vlr::read_from(&bytes[at as usize..], true)
            .map_err(|e| Error::format(path, at, format!("unreadable EVLR {k}: {e}")))?;
        at += EVLR_HEADER_SIZE + data_len;
        vlrs.push(Vlr::from_raw(v, true));
    }
    Ok(())
}

impl LasHeader {
    /// Parses and validates the header and VLRs at the start of `bytes` (the whole file).
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<LasHeader> {
        let (major, minor) = check_start(path, bytes)?;
        let raw = las::raw::Header::read_from(bytes)
            .map_err(|e| Error::format(path, 0, format!("unreadable LAS header: {e}")))?;
        let need = las::Version::new(major, minor).header_size() as u64;
        if (raw.header_size as u64) < need {
            return Err(Error::format(
                path,
                off::HEADER_SIZE,
                format!(
                    "header size {} is smaller than a LAS {major}.{minor} header ({need} bytes)",
                    raw.header_size
                ),
            ));
        }
        let (point_format, compressed) = check_point_format(path, &raw, (major, minor))?;
        let record_length = raw.point_data_record_length;
        let (scale, offset) = check_scale_offset(path, &raw)?;
        let point_count = check_point_count(path, &raw)?;
        let offset_to_points = check_offset_to_points(path, &raw, bytes.len() as u64)?;
        let mut vlrs = read_vlrs(path, bytes, &raw, offset_to_points)?;
        read_evlrs(path, bytes, &raw, offset_to_points, &mut vlrs)?;
        let crs = Crs::from_vlrs(&vlrs);
        let compressed = compressed || vlrs.iter().any(Vlr::is_laszip);
        Ok(LasHeader {
            raw,
            version: (major, minor),
            point_format,
            compressed,
            record_length,
            point_count,
            offset_to_points,
            scale,
            offset,
            vlrs,
            crs,
        })
    }

    /// The LASzip VLR, for compressed files.
    pub fn laszip_vlr(&self) -> Option<&Vlr> {
        self.vlrs.iter().find(|v| v.is_laszip())
    }

    /// Header bounds as a [`super::Bounds`].
    pub fn bounds(&self) -> super::Bounds {
        super::Bounds {
            min: [self.raw.min_x, self.raw.min_y, self.raw.min_z],
            max: [self.raw.max_x, self.raw.max_y, self.raw.max_z],
        }
    }
}
