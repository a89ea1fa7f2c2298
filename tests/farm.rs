//! End-to-end on a real render farm (issue #20): a one-node Slurm cluster started on this
//! machine (scripts/farm/slurm-local.sh: munge, slurmctld, slurmd, state in a temporary
//! directory) runs a 3-frame sequence as an array job (scripts/farm/slurm-submit.sh), a task
//! cancelled mid-frame leaves no partial file and a resubmission finishes the sequence; and
//! the Open Job Description template runs under openjd-cli. Both need root and the packages
//! of scripts/install-deps.sh; not root, they fail unless NIMBUS_SKIP_ROOT_TESTS=1.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

mod common;

use common::{bin, read_rgba, root_or_skip, run, write_ball, RENDER};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Small and quick frames (common::RENDER), quietly.
const QUIET: &str = "-q";

/// The cluster, stopped however the test ends.
struct Cluster {
    dir: PathBuf,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let cluster = Cluster { dir: dir.to_path_buf() };
        run(Command::new(repo().join("scripts/farm/slurm-local.sh")).arg("start").arg(dir).arg("2"));
        cluster
    }

    fn conf(&self) -> PathBuf {
        self.dir.join("slurm.conf")
    }

    fn command(&self, name: &str) -> Command {
        let mut c = Command::new(name);
        c.env("SLURM_CONF", self.conf());
        c
    }

    /// Whether the job still has tasks queued or running.
    fn active(&self, job: &str) -> bool {
        let out = run(self.command("squeue").args(["-h", "-j", job, "-o", "%i %T"]));
        !String::from_utf8_lossy(&out.stdout).trim().is_empty()
    }

    fn wait(&self, job: &str, limit: Duration) {
        let start = Instant::now();
        while self.active(job) {
            assert!(start.elapsed() < limit, "job {job} still running after {limit:?}");
            std::thread::sleep(Duration::from_millis(300));
        }
    }

    /// Each array task's state, from scontrol (kept MinJobAge seconds after the end).
    fn states(&self, job: &str) -> Vec<String> {
        let out = run(self.command("scontrol").args(["show", "job", job, "-o"]));
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| l.split_whitespace().find_map(|w| w.strip_prefix("JobState=")).map(str::to_string))
            .collect()
    }

    /// The state of array task `task` of `job`.
    fn task_state(&self, job: &str, task: u32) -> Option<String> {
        let out = self.command("scontrol").args(["show", "job", &format!("{job}_{task}"), "-o"]).output().ok()?;
        String::from_utf8_lossy(&out.stdout).split_whitespace().find_map(|w| w.strip_prefix("JobState=")).map(str::to_string)
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new(repo().join("scripts/farm/slurm-local.sh")).arg("stop").arg(&self.dir).status();
    }
}

fn submit(cluster: &Cluster, dir: &Path, out_dir: &str, frames: &str, chunk: &str, max_running: &str, extra: &[&str]) -> String {
    let out = run(cluster
        .command(repo().join("scripts/farm/slurm-submit.sh").to_str().unwrap())
        .current_dir(dir)
        .env("NIMBUS_RENDER", bin("nimbus-render"))
        .args(["p.$F4.ply", "-o", &format!("{out_dir}/i.$F4.exr"), "--frames", frames, "--chunk", chunk, "--max-running", max_running, "--log-dir", "logs", "--"])
        .args(RENDER)
        .arg(QUIET)
        .args(extra));
    let job = String::from_utf8_lossy(&out.stdout).trim().to_string();
    assert!(!job.is_empty() && job.chars().all(|c| c.is_ascii_digit()), "sbatch --parsable printed the job id: '{job}'");
    job
}

fn files(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir).map(|d| d.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect()).unwrap_or_default();
    names.sort();
    names
}

#[test]
fn slurm_renders_a_sequence_and_a_cancelled_task_costs_no_frame() {
    if !root_or_skip("the Slurm test (starts slurmctld and slurmd)") {
        return;
    }
    for tool in ["slurmctld", "slurmd", "munged", "sbatch"] {
        assert!(Command::new("sh").args(["-c", &format!("command -v {tool}")]).output().unwrap().status.success(), "{tool} is not installed: run scripts/install-deps.sh");
    }
    let dir = common::scratch("farm", "slurm");
    for f in 1..=3 {
        write_ball(&dir.join(format!("p.{f:04}.ply")), 1200, 0.2 * f as f64);
    }
    let cluster = Cluster::start(&dir.join("cluster"));

    // Three frames, one a task, two tasks at a time.
    let job = submit(&cluster, &dir, "frames", "1-3", "1", "2", &[]);
    cluster.wait(&job, Duration::from_secs(300));
    assert_eq!(cluster.states(&job), ["COMPLETED"; 3], "logs: {:?}", files(&dir.join("logs")));
    assert_eq!(files(&dir.join("frames")), ["i.0001.exr", "i.0002.exr", "i.0003.exr"]);
    // The farm's frame is the one a local run renders.
    run(Command::new(bin("nimbus-render")).current_dir(&dir).args(["p.####.ply", "-o", "local/i.####.exr", "--frame", "2"]).args(RENDER).arg(QUIET));
    assert_eq!(std::fs::read(dir.join("frames/i.0002.exr")).unwrap(), std::fs::read(dir.join("local/i.0002.exr")).unwrap());
    for f in 1..=3 {
        assert!(read_rgba(&dir.join(format!("frames/i.{f:04}.exr"))).iter().any(|p| p[3] > 0.05), "frame {f} shows the ball");
    }

    // Slow frames (many paths, many samples), one task at a time; cancel the first task
    // while it renders.
    let slow = ["--vdbcache", "--paths 4000", "--vdbmarch", "--spp 64"];
    let job = submit(&cluster, &dir, "slow", "1-3", "1", "1", &slow);
    let start = Instant::now();
    while cluster.task_state(&job, 0).as_deref() != Some("RUNNING") {
        assert!(start.elapsed() < Duration::from_secs(60), "task 0 never ran");
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_millis(1500));
    assert!(files(&dir.join("slow")).is_empty(), "task 0 still mid-frame when cancelled: {:?}", files(&dir.join("slow")));
    run(cluster.command("scancel").arg(format!("{job}_0")));
    cluster.wait(&job, Duration::from_secs(300));
    assert_eq!(cluster.task_state(&job, 0).as_deref(), Some("CANCELLED"));
    // The cancelled frame left nothing behind, not even a hidden temporary file.
    assert_eq!(files(&dir.join("slow")), ["i.0002.exr", "i.0003.exr"], "the other tasks ran; frame 1 left no partial file");
    let done: Vec<_> = ["i.0002.exr", "i.0003.exr"].iter().map(|n| std::fs::metadata(dir.join("slow").join(n)).unwrap().modified().unwrap()).collect();

    // The same submission again: --skip-existing renders only frame 1.
    let job = submit(&cluster, &dir, "slow", "1-3", "1", "1", &slow);
    cluster.wait(&job, Duration::from_secs(300));
    assert_eq!(cluster.states(&job), ["COMPLETED"; 3]);
    assert_eq!(files(&dir.join("slow")), ["i.0001.exr", "i.0002.exr", "i.0003.exr"]);
    let again: Vec<_> = ["i.0002.exr", "i.0003.exr"].iter().map(|n| std::fs::metadata(dir.join("slow").join(n)).unwrap().modified().unwrap()).collect();
    assert_eq!(done, again, "finished frames were not rendered again");
    assert!(read_rgba(&dir.join("slow/i.0001.exr")).iter().any(|p| p[3] > 0.05));
    drop(cluster);
    std::fs::remove_dir_all(&dir).ok();
}

/// openjd-cli: NIMBUS_OPENJD, else the venv scripts/install-deps.sh makes, else PATH.
fn openjd() -> PathBuf {
    if let Ok(p) = std::env::var("NIMBUS_OPENJD") {
        return p.into();
    }
    let home = std::env::var("HOME").unwrap_or_else(|_| "/root".into());
    let venv = PathBuf::from(home).join(".cache/nimbus/openjd/bin/openjd");
    if venv.is_file() {
        return venv;
    }
    "openjd".into()
}

#[test]
fn the_openjd_template_renders_a_sequence_in_chunks() {
    let openjd = openjd();
    let found = Command::new(&openjd).arg("--help").output().is_ok_and(|o| o.status.success());
    assert!(found, "openjd-cli not found ({}): run scripts/install-deps.sh, which installs it into ~/.cache/nimbus/openjd", openjd.display());
    let template = repo().join("farm/nimbus-render.openjd.yaml");
    let out = run(Command::new(&openjd).arg("check").arg(&template));
    assert!(String::from_utf8_lossy(&out.stdout).contains("passes validation"), "{}", String::from_utf8_lossy(&out.stdout));

    let dir = common::scratch("farm", "openjd");
    for f in 1..=3 {
        write_ball(&dir.join(format!("p.{f:04}.ply")), 1200, 0.2 * f as f64);
    }
    let extra = RENDER.iter().chain(&[QUIET]).map(|w| format!("'{w}'")).collect::<Vec<_>>().join(" ");
    let out = run(Command::new(&openjd).current_dir(&dir).arg("run").arg(&template).args(["--step", "Render"]).args([
        "-p".to_string(),
        "Input=p.$F4.ply".into(),
        "-p".into(),
        "Output=frames/i.$F4.exr".into(),
        "-p".into(),
        "Frames=1-3".into(),
        "-p".into(),
        "ChunkSize=2".into(),
        "-p".into(),
        format!("NimbusRender={}", bin("nimbus-render").display()),
        "-p".into(),
        format!("WorkDir={}", dir.display()),
        "-p".into(),
        format!("ExtraArgs={extra}"),
    ]));
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(report.contains("Chunks run: 2"), "frames 1-2 and 3: {report}");
    assert_eq!(files(&dir.join("frames")), ["i.0001.exr", "i.0002.exr", "i.0003.exr"], "{report}");
    run(Command::new(bin("nimbus-render")).current_dir(&dir).args(["p.####.ply", "-o", "local/i.####.exr", "--frame", "3"]).args(RENDER).arg(QUIET));
    assert_eq!(std::fs::read(dir.join("frames/i.0003.exr")).unwrap(), std::fs::read(dir.join("local/i.0003.exr")).unwrap());
    std::fs::remove_dir_all(&dir).ok();
}
