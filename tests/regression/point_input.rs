//! Regressions: point_input. Issue 14's point-cloud, pipeline-file and terrain-CLI cases:
//! each bad input must give one line naming the file and the place, exit 2, no panic, no
//! abort, no hang and no allocation its bytes cannot justify.

use crate::common::{self, terratile, Run};
use std::path::Path;

use crate::point_corpus as corpus;

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) {
    std::fs::write(dir.join(name), bytes).unwrap();
}

/// A pipeline reading `input`, writing no meshes, with `extra` TOML appended.
fn pipeline(dir: &Path, input: &str, extra: &str) {
    common::write_pipeline(dir, input, &format!("meshes = []\n{extra}"));
}

/// A pipeline reading `a.xyz`, a grid of `points` points written beside it, with `extra`
/// TOML appended.
fn xyz_job(dir: &Path, points: usize, extra: &str) {
    write(dir, "a.xyz", corpus::xyz_grid(points));
    pipeline(dir, "a.xyz", extra);
}

/// The same within a memory budget (`--max-memory`).
fn run_within(dir: &Path, budget: &str) -> Run {
    terratile(dir, &["--max-memory", budget, "run", "-q", "p.toml"])
}

/// The run within `budget` must fail with `needles` before writing any output.
fn refused_within(dir: &Path, budget: &str, needles: &[&str]) {
    run_within(dir, budget)
        .input_error(needles)
        .left_nothing("out");
}

fn info(dir: &Path, file: &str) -> Run {
    terratile(dir, &["info", "-q", file])
}

// A LAS 1.4 EVLR length of 2^35 made `info` abort allocating 32 GiB (exit 134, no file name).
#[test]
fn las14_evlr_length_2_35_is_an_error_not_an_abort() {
    let d = tempfile::tempdir().unwrap();
    write(
        d.path(),
        "e.las",
        corpus::las14(10, Some(1 << 35), None, 0.01, 0.0),
    );
    info(d.path(), "e.las").input_error(&["e.las: byte 595:", "EVLR 0", "34359738368"]);
}

// The same with 2^62: a 4 EiB allocation.
#[test]
fn las14_evlr_length_2_62_is_an_error_not_an_abort() {
    let d = tempfile::tempdir().unwrap();
    write(
        d.path(),
        "e.las",
        corpus::las14(10, Some(1 << 62), None, 0.01, 0.0),
    );
    info(d.path(), "e.las").input_error(&["e.las: byte 595:", "EVLR 0"]);
}

// An EVLR offset of 1 read garbage from the header as an EVLR length (16 GB allocation).
#[test]
fn las14_evlr_offset_1_is_an_error_at_the_offset_field() {
    let d = tempfile::tempdir().unwrap();
    write(
        d.path(),
        "e.las",
        corpus::las14(10, None, Some(1), 0.01, 0.0),
    );
    info(d.path(), "e.las").input_error(&["e.las: byte 235:", "first EVLR offset 1"]);
    // A sound EVLR table still reads.
    write(d.path(), "ok.las", corpus::las14(10, None, None, 0.01, 0.0));
    info(d.path(), "ok.las").ok();
}

// A LAZ point count of 0xFFFFFFFF reserved 116 GiB before the chunk table was checked.
#[test]
fn laz_point_count_ffffffff_is_checked_against_the_chunk_table() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "c.laz", corpus::laz_with_count(u32::MAX));
    info(d.path(), "c.laz").input_error(&["c.laz: byte 107:", "chunk table holds at most"]);
    terratile(d.path(), &["convert", "c.laz", "o.las"])
        .input_error(&["c.laz: byte 107:"])
        .left_nothing("o.las");
}

// 2^31 points: `convert` tried to allocate 60 GB for the decompressed records.
#[test]
fn laz_point_count_2_31_is_checked_against_the_chunk_table() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "c.laz", corpus::laz_with_count(1 << 31));
    info(d.path(), "c.laz").input_error(&["c.laz: byte 107:"]);
    terratile(d.path(), &["convert", "c.laz", "o.las"]).input_error(&["c.laz: byte 107:"]);
}

// A damaged chunk table made `info` print "panicked … capacity overflow" before its error.
#[test]
fn laz_damaged_chunk_table_prints_no_panic() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "c.laz", corpus::laz_junk_chunk_table());
    let r = info(d.path(), "c.laz");
    r.input_error(&["c.laz: byte"]);
    assert!(!r.stderr.contains("capacity overflow"), "{}", r.context());
}

// A scale of 1e308 gave `x inf .. inf` in `info` and NaN later.
#[test]
fn las_scale_1e308_is_rejected_at_the_scale_field() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "s.las", corpus::las14(10, None, None, 1e308, 0.0));
    info(d.path(), "s.las").input_error(&["s.las: byte 131:", "x scale factor"]);
    pipeline(d.path(), "s.las", "");
    common::run_p_toml(d.path())
        .input_error(&["s.las: byte 131:"])
        .left_nothing("out");
}

// An offset of 1.7e308 was accepted likewise.
#[test]
fn las_offset_1_7e308_is_rejected_at_the_offset_field() {
    let d = tempfile::tempdir().unwrap();
    write(
        d.path(),
        "o.las",
        corpus::las14(10, None, None, 0.01, 1.7e308),
    );
    info(d.path(), "o.las").input_error(&["o.las: byte 155:", "x offset"]);
}

// `terratile run /dev/zero` read 4.1 GB of pipeline.
#[test]
fn pipeline_from_dev_zero_is_refused() {
    let d = tempfile::tempdir().unwrap();
    terratile(d.path(), &["run", "/dev/zero"])
        .input_error(&["/dev/zero: pipeline file is a device"]);
}

// A pipeline file has a size limit (1 MiB).
#[test]
fn pipeline_larger_than_1_mib_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let mut text = String::from("[input]\npaths = [\"a.xyz\"]\n");
    while text.len() <= 1 << 20 {
        text.push_str("# padding padding padding padding padding padding padding\n");
    }
    write(d.path(), "big.toml", text);
    terratile(d.path(), &["run", "big.toml"]).input_error(&["big.toml: pipeline file is larger"]);
}

/// Runs `args` in `dir`, killing it after 30 s (a FIFO read blocks forever).
fn bounded(dir: &Path, args: &[&str]) -> Run {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_terratile"))
        .args(args)
        .current_dir(dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t.elapsed().as_secs() > 30 {
            child.kill().unwrap();
            panic!("terratile {} hung", args.join(" "));
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    Run::from_output(dir, args, out)
}

// A FIFO given as input blocked forever; in `paths` it was said not to exist.
#[cfg(unix)]
#[test]
fn fifo_input_is_refused_not_read() {
    let d = tempfile::tempdir().unwrap();
    let made = std::process::Command::new("mkfifo")
        .arg(d.path().join("f.las"))
        .status()
        .unwrap();
    assert!(made.success());
    bounded(d.path(), &["info", "-q", "f.las"]).input_error(&["f.las: is a FIFO"]);
    pipeline(d.path(), "f.las", "");
    bounded(d.path(), &["run", "-q", "p.toml"]).input_error(&[
        "p.toml:2:",
        "input.paths",
        "f.las is a FIFO",
    ]);
    bounded(d.path(), &["run", "-q", "f.las"]).input_error(&["f.las: pipeline file is a FIFO"]);
}

// A directory as input said "No such device".
#[test]
fn directory_input_is_refused_clearly() {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("dir.las")).unwrap();
    info(d.path(), "dir.las").input_error(&["dir.las: is a directory"]);
    pipeline(d.path(), "dir.las", "");
    common::run_p_toml(d.path()).input_error(&["input.paths", "is a directory"]);
}

// `resample.size = [46000, 46000]` on 2,500 points allocated tens of GB and aborted.
#[test]
fn resample_size_46000_is_refused_by_the_memory_estimate() {
    let d = tempfile::tempdir().unwrap();
    xyz_job(d.path(), 2500, "[resample]\nsize = [46000, 46000]\n");
    refused_within(
        d.path(),
        "8GiB",
        &[
            "p.toml:7:1: resample.size:",
            "memory budget of 8.00 GiB",
            "GiB",
        ],
    );
}

// The budget is a global option; a small one refuses an ordinary run before the work.
#[test]
fn max_memory_refuses_a_run_that_needs_more() {
    let d = tempfile::tempdir().unwrap();
    xyz_job(d.path(), 40_000, "");
    refused_within(
        d.path(),
        "64KiB",
        &[
            "p.toml:",
            "memory budget of 65536 bytes",
            "raise --max-memory",
        ],
    );
    let r = run_within(d.path(), "lots");
    assert_eq!(r.code, 2, "{}", r.context());
    assert!(r.stderr.contains("`lots` is not a size"), "{}", r.context());
    run_within(d.path(), "1GiB").ok();
}

// `cell_size = 0.02` and `denoise.voxel_size = 0.025` on autzen_trim aborted after
// allocating tens of GB.
#[test]
fn tiny_cells_and_voxels_on_a_real_survey_are_refused() {
    let Some(f) = common::data_file("lidar/autzen_trim.las") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let f = f.display().to_string();
    pipeline(d.path(), &f, "[resample]\ncell_size = 0.02\n");
    refused_within(d.path(), "8GiB", &["p.toml:7:1: resample.cell_size:"]);
    pipeline(d.path(), &f, "[denoise]\nvoxel_size = 0.025\n");
    refused_within(
        d.path(),
        "8GiB",
        &["p.toml:7:1: denoise.voxel_size:", "noise removal's voxels"],
    );
}

// One far-away point (1e15 or 1e16) made denoise take 20 s and 3.7 GB, or abort: the voxel
// bookkeeping grew with the bounding box.
#[test]
fn one_far_away_point_keeps_denoise_small() {
    for far in ["1e15", "1e16"] {
        let d = tempfile::tempdir().unwrap();
        write(
            d.path(),
            "a.xyz",
            corpus::xyz_grid(1600) + &format!("{far} 2005 100\n"),
        );
        pipeline(d.path(), "a.xyz", "");
        let t = std::time::Instant::now();
        run_within(d.path(), "1GiB").ok();
        assert!(t.elapsed().as_secs() < 20, "{far}: {:?}", t.elapsed());
    }
}

// Points at ±1e308 overflowed the span to infinity, and the error said the points spanned a
// "zero-width range (x inf, y inf)": the opposite of the truth.
#[test]
fn an_infinite_span_is_not_called_zero_width() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "a.xyz", "1e308 1e308 1\n-1e308 -1e308 2\n0 0 0\n");
    pipeline(d.path(), "a.xyz", "");
    refused_within(
        d.path(),
        "1GiB",
        &["denoise.voxel_size:", "too large to measure"],
    );
}

// `--threads 100000` ran a minute and aborted.
#[test]
fn threads_100000_is_refused() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "a.xyz", corpus::xyz_grid(100));
    terratile(d.path(), &["--threads", "100000", "info", "a.xyz"])
        .input_error(&["--threads 100000: at most"]);
}

// `generate --tiles 100000x100000`, `--points 1e12` and `--size 1e8x1e8` ran a minute and
// aborted.
#[test]
fn generate_counts_are_bounded() {
    let d = tempfile::tempdir().unwrap();
    for (args, needle) in [
        (&["--tiles", "100000x100000"][..], "--tiles 100000x100000"),
        (&["--points", "1000000000000"][..], "--points 1000000000000"),
        (&["--size", "1e8x1e8"][..], "--size 100000000x100000000"),
    ] {
        let mut a = vec!["generate", "-o", "g.las"];
        a.extend_from_slice(args);
        terratile(d.path(), &a)
            .input_error(&[needle])
            .left_nothing("g.las");
    }
}

// A zero-point LAS said "no points left after the class filter" with no filter set.
#[test]
fn zero_point_las_names_the_file() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "z.las", corpus::las14(0, None, None, 0.01, 0.0));
    pipeline(d.path(), "z.las", "");
    let r = common::run_p_toml(d.path());
    r.input_error(&["p.toml:2:1: input.paths:", "z.las: 0 points"]);
    assert!(!r.stderr.contains("class filter"), "{}", r.context());
}

// `max_points = 0` and a class filter that removes everything gave no pipeline line.
#[test]
fn empty_selection_names_the_pipeline_key() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "a.las", corpus::las_format3(400, 0, false));
    pipeline(d.path(), "a.las", "");
    let p = std::fs::read_to_string(d.path().join("p.toml")).unwrap();
    write(
        d.path(),
        "p.toml",
        p.replace("[input]\n", "[input]\nmax_points = 0\n"),
    );
    common::run_p_toml(d.path())
        .input_error(&["p.toml:2:1: input.max_points: 0: must be at least 1"]);
    write(
        d.path(),
        "p.toml",
        p.replace("[input]\n", "[input]\nkeep_classes = [31]\n"),
    );
    common::run_p_toml(d.path()).input_error(&[
        "p.toml:2:1: input.keep_classes:",
        "keeps none of the 400 points",
        "a.las",
    ]);
}

// One, identical or collinear points said "denoise: … zero-width range" with no file.
#[test]
fn degenerate_points_name_the_pipeline_key() {
    for (_name, text) in [
        ("one", "1 2 3\n".to_string()),
        ("same", "1 2 3\n".repeat(50)),
        ("line", (0..100).map(|i| format!("{i} 5 1\n")).collect()),
    ] {
        let d = tempfile::tempdir().unwrap();
        write(d.path(), "a.xyz", text);
        pipeline(d.path(), "a.xyz", "");
        common::run_p_toml(d.path()).input_error(&[
            "p.toml:",
            "denoise.voxel_size",
            "zero-width range",
        ]);
        // Without denoise, resample names the pipeline file and the stage.
        pipeline(d.path(), "a.xyz", "[denoise]\nenabled = false\n");
        common::run_p_toml(d.path()).input_error(&[
            "p.toml:",
            "p.toml: resample: ",
            "one line or one spot",
        ]);
    }
}

// A too-small voxel size gave no pipeline line.
#[test]
fn too_small_voxels_and_cells_name_the_key() {
    let d = tempfile::tempdir().unwrap();
    xyz_job(d.path(), 1600, "[denoise]\nvoxel_size = 1e-9\n");
    common::run_p_toml(d.path()).input_error(&["p.toml:7:1: denoise.voxel_size:", "too small"]);
    pipeline(d.path(), "a.xyz", "[resample]\ncell_size = 1e-9\n");
    common::run_p_toml(d.path()).input_error(&["p.toml:7:1: resample.cell_size:"]);
}

// One non-UTF-8 byte in an XYZ said "neither LASF nor text at byte 0".
#[test]
fn non_utf8_byte_in_xyz_names_its_line() {
    let d = tempfile::tempdir().unwrap();
    let mut bytes = corpus::xyz_grid(100).into_bytes();
    bytes.extend_from_slice(b"1 2 \xff3\n");
    write(d.path(), "a.xyz", &bytes);
    info(d.path(), "a.xyz").input_error(&["a.xyz:101: column 3"]);
    // Binary that is not LAS names the first byte that is not text.
    write(d.path(), "b.bin", b"12 3 4\n\x01\x02");
    info(d.path(), "b.bin").input_error(&["b.bin: byte 7:", "0x01"]);
}

// `resample.size = [64, 64, 99999]` and `extract.viewpoint = [x, y, z, 7]` dropped the
// extra elements silently.
#[test]
fn config_arrays_with_extra_elements_are_refused() {
    let d = tempfile::tempdir().unwrap();
    xyz_job(d.path(), 1600, "[resample]\nsize = [64, 64, 99999]\n");
    common::run_p_toml(d.path()).input_error(&["p.toml:7:", "resample.size", "invalid length 3"]);
    pipeline(
        d.path(),
        "a.xyz",
        "[extract]\nviewpoint = [1.0, 2.0, 3.0, 7.0]\n",
    );
    common::run_p_toml(d.path()).input_error(&[
        "p.toml:7:",
        "extract.viewpoint",
        "invalid length 4",
    ]);
    pipeline(d.path(), "a.xyz", "[resample]\nsize = [64]\n");
    common::run_p_toml(d.path()).input_error(&["resample.size", "length 1"]);
}

/// The point records of a LAS file (format 0–5 layout), with the class bits cleared.
fn records(bytes: &[u8]) -> (u8, Vec<Vec<u8>>) {
    let at = u32::from_le_bytes(bytes[96..100].try_into().unwrap()) as usize;
    let len = u16::from_le_bytes(bytes[105..107].try_into().unwrap()) as usize;
    let recs = bytes[at..]
        .chunks_exact(len)
        .map(|r| {
            let mut r = r.to_vec();
            r[15] &= 0xE0;
            r
        })
        .collect();
    (bytes[104] & 0x3F, recs)
}

// `noise.las` was LAS 1.2 point format 0 even from point format 3 input: colour and GPS
// time were lost.
#[test]
fn noise_las_keeps_the_input_point_format() {
    for compressed in [false, true] {
        let d = tempfile::tempdir().unwrap();
        let input = corpus::las_format3(3000, 5, compressed);
        write(d.path(), "a.las", &input);
        pipeline(d.path(), "a.las", "[denoise]\nwrite_removed = true\n");
        common::run_p_toml(d.path()).ok();
        let noise = std::fs::read(d.path().join("out/noise.las")).unwrap();
        let (format, removed) = records(&noise);
        assert_eq!(format, 3, "compressed {compressed}");
        assert!(!removed.is_empty(), "no point removed");
        assert!(noise[d_class_offset(&noise)] & 0x1F == 7);
        if !compressed {
            let (_, all) = records(&input);
            for r in &removed {
                assert!(all.contains(r), "a noise record is not an input record");
            }
        }
    }
}

/// Byte offset of the first record's class byte.
fn d_class_offset(bytes: &[u8]) -> usize {
    u32::from_le_bytes(bytes[96..100].try_into().unwrap()) as usize + 15
}
