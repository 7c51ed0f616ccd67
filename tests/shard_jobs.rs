//! The sharded run as separate jobs (`terratile plan`, `shard`, `merge`) against
//! `terratile run`: byte-identical output trees on real surveys; bad input (no plan, an
//! index out of range, a phase run too early, a corrupt or foreign result, an input changed
//! since planning) refused in one line with exit 2; and the Dask driver
//! (`scale/dask_run.py`) on a LocalCluster of 2 workers, also with a worker killed mid-run,
//! in a Python environment this test builds under `target/dask-py` from the package
//! registry (skipped, saying why, when that is impossible); the Slurm recipe with a
//! stand-in `sbatch`.

use crate::common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

const PHASES: [&str; 4] = ["count", "keep", "prepare", "finish"];

/// A pipeline on `input` writing to `out`, with `extra` TOML appended.
fn pipeline(dir: &Path, name: &str, input: &Path, out: &str, extra: &str) {
    let toml = format!(
        "[input]\npaths = [{:?}]\n[output]\ndir = {out:?}\n{extra}\n",
        input.to_str().unwrap()
    );
    std::fs::write(dir.join(name), toml).unwrap();
}

/// The jobs of every phase in turn, in this process's order (any order within a phase
/// gives the same result), then the merge.
fn run_jobs(dir: &Path, work: &str, jobs: usize) {
    for phase in PHASES {
        for k in 0..jobs {
            let k = k.to_string();
            terratile(dir, &["shard", work, "--phase", phase, "--index", &k]).ok();
        }
    }
    terratile(dir, &["merge", work, "--quiet"]).ok();
}

/// `run` and plan + shard × jobs + merge on `input` give the same bytes; returns the
/// directory of both.
pub(crate) fn check_identical(input: &Path, extra: &str, shards: usize) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    pipeline(d, "run.toml", input, "out-run", extra);
    pipeline(d, "jobs.toml", input, "out-jobs", extra);
    terratile(d, &["run", "run.toml", "--quiet"]).ok();
    let plan = terratile(
        d,
        &[
            "plan",
            "jobs.toml",
            "--out",
            "work",
            "--shards",
            &shards.to_string(),
            "--json",
        ],
    );
    let plan: serde_json::Value = serde_json::from_str(&plan.ok().stdout).unwrap();
    let jobs = plan["jobs"].as_u64().unwrap() as usize;
    run_jobs(d, "work", jobs);
    same_tree(&d.join("out-run"), &d.join("out-jobs"));
    no_temporaries(d, "after the jobs");
    // A rerun of a finished job writes the same bytes (jobs are idempotent).
    let r = d.join("work/shards/0/finish.bin");
    let before = std::fs::read(&r).unwrap();
    terratile(d, &["shard", "work", "--phase", "finish", "--index", "0"]).ok();
    assert!(
        std::fs::read(&r).unwrap() == before,
        "a rerun changed its result"
    );
    dir
}

#[test]
fn jobs_match_run_on_csite4() {
    let Some(f) = data_file("lidar/CSite4_orig-utm.laz") else {
        return;
    };
    // 6 × 6 tiles of 129 samples in 2 × 2 blocks; then the default tiles in a 3 × 3 grid of
    // shards wider than the 3 × 3 tiles, with the nodata fill (holes kept: no meshes).
    check_identical(&f, "[tiles]\nsize = 129\n", 4);
    check_identical(
        &f,
        "meshes = []\nwireframe = false\n[fill]\nfallback = \"nodata\"\n",
        9,
    );
    // Noise removal off (its two phases write empty results) in a 1 × 3 shard grid.
    check_identical(&f, "[denoise]\nenabled = false\n", 3);
}

#[test]
fn jobs_match_run_on_autzen_trim() {
    let Some(f) = data_file("lidar/autzen_trim.las") else {
        return;
    };
    check_identical(&f, "[tiles]\nsize = 129\n", 6);
}

#[test]
fn jobs_match_run_on_bcts_3_with_taller_voxels() {
    // More than 1 % of bcts_3's points fail the count at voxels one spacing tall: the
    // `count` jobs' filter at height steps 1 is not the answer, and the `keep` jobs read
    // their windows again and filter them at the height the summed counts choose.
    let Some(f) = data_file("lidar/bcts_3.laz") else {
        return;
    };
    let dir = check_identical(
        &f,
        "meshes = []\nwireframe = false\n[tiles]\nsize = 129\n",
        4,
    );
    // The height steps a `keep` result holds: its payload's first value, after the header.
    let keep = std::fs::read(dir.path().join("work/shards/0/keep.bin")).unwrap();
    let q = u64::from_le_bytes(keep[40..48].try_into().unwrap());
    assert!(q > 1, "voxel height steps {q}");
}

/// A planned CSite4 run with every phase done, in a temporary directory.
fn planned() -> Option<(tempfile::TempDir, PathBuf)> {
    let f = data_file("lidar/CSite4_orig-utm.laz")?;
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.laz");
    std::fs::copy(&f, &input).unwrap();
    pipeline(dir.path(), "p.toml", &input, "out", "[tiles]\nsize = 129\n");
    terratile(
        dir.path(),
        &["plan", "p.toml", "--out", "work", "--shards", "2"],
    )
    .ok();
    Some((dir, input))
}

#[test]
fn job_bad_input_is_one_line_exit_2() {
    let Some((dir, input)) = planned() else {
        return;
    };
    let d = dir.path();
    // No plan in the directory.
    std::fs::create_dir(d.join("empty")).unwrap();
    terratile(d, &["shard", "empty", "--phase", "count", "--index", "0"]).input_error(&[
        "plan.json",
        "no plan",
        "terratile plan",
    ]);
    terratile(d, &["merge", "empty"]).input_error(&["no plan"]);
    // An index out of range, a phase that does not exist, no index at all.
    terratile(d, &["shard", "work", "--phase", "count", "--index", "2"])
        .input_error(&["--index 2", "jobs 0 to 1"]);
    terratile(d, &["shard", "work", "--phase", "dance", "--index", "0"])
        .input_error(&["--phase dance"]);
    let r = run_with(
        {
            let mut c = Command::new(env!("CARGO_BIN_EXE_terratile"));
            c.env_remove("SLURM_ARRAY_TASK_ID")
                .env_remove("JOB_COMPLETION_INDEX");
            c
        },
        d,
        &["shard", "work", "--phase", "count"],
    );
    r.input_error(&["no job index"]);
    // The index from a Slurm array's variable; a phase before the one it needs.
    let mut slurm = Command::new(env!("CARGO_BIN_EXE_terratile"));
    slurm.env("SLURM_ARRAY_TASK_ID", "1");
    run_with(slurm, d, &["shard", "work", "--phase", "count"]).ok();
    terratile(d, &["shard", "work", "--phase", "keep", "--index", "1"])
        .input_error(&["shards/0/count.bin", "no result of this job yet"]);
    run_jobs_from(d, "count");
    // A corrupt result: one flipped byte, then a truncated file, then a result of another
    // index put in its place.
    let r = d.join("work/shards/1/finish.bin");
    let good = std::fs::read(&r).unwrap();
    let mut bad = good.clone();
    let last = bad.len() - 1;
    bad[last] ^= 0x40;
    std::fs::write(&r, &bad).unwrap();
    terratile(d, &["merge", "work"]).input_error(&["finish.bin", "byte 32", "checksum"]);
    std::fs::write(&r, &good[..good.len() / 2]).unwrap();
    terratile(d, &["merge", "work"]).input_error(&["finish.bin", "byte 24"]);
    std::fs::copy(d.join("work/shards/0/finish.bin"), &r).unwrap();
    terratile(d, &["merge", "work"]).input_error(&["finish.bin", "byte 16", "another job"]);
    assert!(!d.join("out").exists(), "no output after a failed merge");
    std::fs::write(&r, &good).unwrap();
    // An input changed since planning.
    let f = std::fs::File::options().append(true).open(&input).unwrap();
    f.set_len(f.metadata().unwrap().len() + 1).unwrap();
    drop(f);
    terratile(d, &["merge", "work"]).input_error(&["in.laz", "changed since", "plan again"]);
    // A pipeline the sharded run cannot do, at its key.
    std::fs::write(
        d.join("g.toml"),
        format!(
            "[input]\npaths = [{:?}]\n[baseline]\nenabled = true\n",
            input.to_str().unwrap()
        ),
    )
    .unwrap();
    terratile(d, &["plan", "g.toml", "--out", "w2"]).input_error(&["baseline.enabled"]);
    // A plan file that is not one is neither read nor overwritten.
    std::fs::create_dir(d.join("mine")).unwrap();
    std::fs::write(d.join("mine/plan.json"), "my notes").unwrap();
    terratile(d, &["plan", "p.toml", "--out", "mine"]).input_error(&["is not a terratile plan"]);
    assert_eq!(
        std::fs::read(d.join("mine/plan.json")).unwrap(),
        b"my notes"
    );
    terratile(d, &["shard", "mine", "--phase", "count", "--index", "0"])
        .input_error(&["mine/plan.json:1", "not a terratile plan"]);
    no_temporaries(d, "after the refusals");
}

/// The jobs of `from` and every later phase, both indices, then the merge.
fn run_jobs_from(d: &Path, from: &str) {
    let start = PHASES.iter().position(|p| *p == from).unwrap();
    for phase in &PHASES[start..] {
        for k in ["0", "1"] {
            terratile(d, &["shard", "work", "--phase", phase, "--index", k]).ok();
        }
    }
}

/// The Python interpreter of `target/dask-py/venv`, with dask and distributed; None (after
/// saying why) when that is impossible.
fn dask_env() -> Option<PathBuf> {
    python_venv("dask-py", &["dask", "distributed"], "dask distributed")
}

/// `terratile run` and `scale/dask_run.py` (2 local workers, `terratile` = `bin`) on CSite4;
/// returns the directory and the driver's run.
fn dask_case(bin: impl Fn(&Path) -> PathBuf) -> Option<(tempfile::TempDir, Run)> {
    let f = data_file("lidar/CSite4_orig-utm.laz")?;
    let py = dask_env()?;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    pipeline(d, "run.toml", &f, "out-run", "[tiles]\nsize = 129\n");
    pipeline(d, "jobs.toml", &f, "out-jobs", "[tiles]\nsize = 129\n");
    terratile(d, &["run", "run.toml", "--quiet"]).ok();
    let bin = bin(d);
    let mut cmd = Command::new(py);
    cmd.arg(repo().join("scale/dask_run.py"));
    let args = [
        "jobs.toml",
        "--work",
        "work",
        "--shards",
        "4",
        "--workers",
        "2",
        "--terratile",
        bin.to_str().unwrap(),
    ];
    let r = run_with(cmd, d, &args);
    r.ok();
    same_tree(&d.join("out-run"), &d.join("out-jobs"));
    // A job orphaned by a killed worker finishes on its own; wait for it before looking.
    for _ in 0..1200 {
        if !d.join("killed").exists() || d.join("killed/done").exists() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    no_temporaries(d, &r.context());
    Some((dir, r))
}

#[test]
fn dask_local_cluster_matches_run() {
    let Some((_dir, r)) = dask_case(|_| PathBuf::from(env!("CARGO_BIN_EXE_terratile"))) else {
        return;
    };
    println!("{}", r.stdout.trim());
}

#[test]
fn dask_survives_a_killed_worker() {
    // The job `prepare 1` kills the Dask worker running it (SIGKILL to its parent) while
    // terratile runs, the first time only: the scheduler must run it again elsewhere.
    let wrapper = |d: &Path| {
        let w = d.join("terratile-killer.sh");
        let script = format!(
            "#!/bin/sh\n\
             if [ \"$4 $5 $6 $7\" = \"--phase prepare --index 1\" ] && mkdir {mark:?} 2>/dev/null; then\n\
               {bin:?} \"$@\" &\n\
               sleep 0.1\n\
               kill -9 $PPID\n\
               wait\n\
               touch {mark:?}/done\n\
               exit 1\n\
             fi\n\
             exec {bin:?} \"$@\"\n",
            mark = d.join("killed").to_str().unwrap(),
            bin = env!("CARGO_BIN_EXE_terratile"),
        );
        std::fs::write(&w, script).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&w, std::fs::Permissions::from_mode(0o755)).unwrap();
        w
    };
    let Some((dir, r)) = dask_case(wrapper) else {
        return;
    };
    assert!(
        dir.path().join("killed").is_dir(),
        "no worker was killed\n{}",
        r.context()
    );
    println!("{}", r.stdout.trim());
}

#[test]
fn slurm_recipe_with_a_stand_in_sbatch() {
    // No Slurm here: a stand-in `sbatch` runs each `--wrap` command at once, for every index
    // of its `--array` (with SLURM_ARRAY_TASK_ID set), in submission order, which is the
    // order the `afterok` dependencies impose. It checks the script's plan, phases, indices
    // and merge, not Slurm itself.
    let Some(f) = data_file("lidar/CSite4_orig-utm.laz") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    pipeline(d, "run.toml", &f, "out-run", "[tiles]\nsize = 129\n");
    pipeline(d, "jobs.toml", &f, "out-jobs", "[tiles]\nsize = 129\n");
    terratile(d, &["run", "run.toml", "--quiet"]).ok();
    let bin = d.join("bin");
    std::fs::create_dir(&bin).unwrap();
    let sbatch = bin.join("sbatch");
    std::fs::write(
        &sbatch,
        "#!/bin/sh\narr=''; wrap=''\nfor a in \"$@\"; do case \"$a\" in --array=*) arr=${a#--array=};; \
         --wrap=*) wrap=${a#--wrap=};; esac; done\nif [ -n \"$arr\" ]; then i=${arr%-*}; \
         n=${arr#*-}; while [ $i -le $n ]; do SLURM_ARRAY_TASK_ID=$i sh -c \"$wrap\" >&2 || exit 1; \
         i=$((i+1)); done; else sh -c \"$wrap\" >&2 || exit 1; fi\necho $$\n",
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&sbatch, std::fs::Permissions::from_mode(0o755)).unwrap();
    let mut cmd = Command::new("sh");
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    cmd.env("PATH", path)
        .env("TERRATILE", env!("CARGO_BIN_EXE_terratile"))
        .arg(repo().join("scale/slurm.sh"));
    let r = run_with(cmd, d, &["jobs.toml", "work", "4"]);
    r.ok();
    assert!(r.stdout.contains("4 jobs per phase"), "{}", r.context());
    same_tree(&d.join("out-run"), &d.join("out-jobs"));
}

/// `run` and the jobs on generated 3 × 3 LAS tiles (a glob) with `input` lines added to
/// `[input]`, in 3 × 3 shards: byte-identical, though each job reads only the tiles its
/// range meets (the `prepare` jobs pass over the keep flags of the tiles they skip).
fn check_identical_on_tiles(d: &Path, input: &str) {
    std::fs::create_dir_all(d.join("tiles")).unwrap();
    let gen = [
        "generate",
        "-o",
        "tiles/s.las",
        "--points",
        "270000",
        "--tiles",
        "3x3",
    ];
    terratile(d, &gen).ok();
    for (name, out) in [("run.toml", "out-run"), ("jobs.toml", "out-jobs")] {
        let toml = format!(
            "[input]\npaths = [\"tiles/*.las\"]\n{input}[output]\ndir = {out:?}\n\
             meshes = []\n[tiles]\nsize = 129\n"
        );
        std::fs::write(d.join(name), toml).unwrap();
    }
    terratile(d, &["run", "run.toml", "--quiet"]).ok();
    let args = ["plan", "jobs.toml", "--out", "work", "--shards", "9"];
    terratile(d, &args).ok();
    run_jobs(d, "work", 9);
    same_tree(&d.join("out-run"), &d.join("out-jobs"));
}

#[test]
fn jobs_read_only_the_tiles_they_need() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    check_identical_on_tiles(d, "");
    // The north-east tile is made unreadable (its header announces one more record than it
    // holds) with its size and modification time kept, so the plan still accepts it: the
    // south-west window's `count` job never reads it and succeeds, the north-east one fails
    // on it.
    let ne = d.join("tiles/s-2-2.las");
    let mtime = std::fs::metadata(&ne).unwrap().modified().unwrap();
    let mut bytes = std::fs::read(&ne).unwrap();
    let n = u32::from_le_bytes(bytes[107..111].try_into().unwrap());
    bytes[107..111].copy_from_slice(&(n + 1).to_le_bytes());
    std::fs::write(&ne, &bytes).unwrap();
    let f = std::fs::OpenOptions::new().write(true).open(&ne).unwrap();
    f.set_modified(mtime).unwrap();
    drop(f);
    terratile(d, &["shard", "work", "--phase", "count", "--index", "0"]).ok();
    let r = terratile(d, &["shard", "work", "--phase", "count", "--index", "8"]);
    r.input_error(&["s-2-2.las"]);
}

#[test]
fn jobs_read_by_bounds_with_a_class_filter_and_a_cap() {
    // The cap ends inside the sixth tile: the sequence of points each job sees, and the keep
    // flags `prepare` passes over, must follow the in-memory reader's.
    let dir = tempfile::tempdir().unwrap();
    check_identical_on_tiles(dir.path(), "drop_classes = [5]\nmax_points = 160000\n");
}
