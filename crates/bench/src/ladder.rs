//! The scenes, the ladder of quality settings, and running the tools.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};

use nimbus_cli::Quality;

use crate::image::{compare, read};
use crate::Args;

/// A bundled scene: the flags the demo renders it with.
struct Scene {
    name: &'static str,
    particles: &'static str,
    density: &'static [&'static str],
    /// Medium and lights (vdbphoton records them; the reference takes them directly).
    optics: &'static [&'static str],
    camera: &'static [&'static str],
    voxel: f64,
}

const SCENES: [Scene; 2] = [
    Scene {
        name: "cloud",
        particles: "data/cloud.ply",
        density: &["--voxel-size", "2"],
        optics: &["--extinction", "30", "--albedo", "0.95", "--g", "0.6", "--sun", "dir=0.5,0.3,-0.8,irradiance=4"],
        camera: &["--eye", "170,-300,160", "--look-at", "170,180,10"],
        voxel: 2.0,
    },
    Scene {
        name: "plume",
        particles: "data/plume.ply",
        density: &["--voxel-size", "1"],
        optics: &["--extinction", "40", "--albedo", "0.8", "--g", "0.3", "--sun", "dir=-0.7,0.5,-0.5,irradiance=5"],
        camera: &[],
        voxel: 1.0,
    },
];

/// One rung of the ladder: the chain as a user runs it, with these flags.
#[derive(Clone, Debug)]
pub struct Rung {
    pub name: String,
    /// vdbphoton's photons and distance sampling, where the rung gathers photons; `None`: no
    /// vdbphoton, vdbcache straight from the density.
    pub photons: Option<(u64, &'static str)>,
    /// vdbcache's flags beyond the camera (and, without photons, the optics).
    pub cache: Vec<String>,
    /// vdbmarch's flags.
    pub march: Vec<String>,
}

impl Rung {
    fn new(name: &str, cache: &[&str], march: &[&str]) -> Rung {
        Rung { name: name.into(), photons: None, cache: strings(cache), march: strings(march) }
    }

    /// The photon chain: vdbphoton, then vdbcache gathering `neighbours` photons.
    fn photons(name: &str, photons: u64, distance: &'static str, neighbours: u32) -> Rung {
        let k = neighbours.to_string();
        Rung { photons: Some((photons, distance)), ..Rung::new(name, &["--gather-neighbours", &k], &[]) }
    }

    /// The distance mode of the photons, or "none".
    pub fn distance(&self) -> &'static str {
        self.photons.map_or("none", |p| p.1)
    }
}

/// The presets (`--quality`), as the tools apply them.
pub fn presets() -> Vec<Rung> {
    Quality::ALL.iter().map(|q| Rung::new(q.name(), &["--quality", q.name()], &["--quality", q.name()])).collect()
}

/// The ladder: the tools' defaults (no flags at all), the presets, the paths and lattices
/// around the defaults, the march's samples and step, and the photon chain (the paper's
/// estimator) over photon counts and the paper's distance modes (they cost more per photon,
/// so each is also scored against delta tracking at equal time:
/// [`Row::delta_rmse_at_equal_time`]).
fn ladder(quick: bool) -> Vec<Rung> {
    let mut rungs = vec![Rung::new("default", &[], &[])];
    rungs.extend(presets());
    if quick {
        rungs.truncate(2);
        return rungs;
    }
    rungs.extend([
        Rung::new("paths 8", &["--paths", "8"], &[]),
        Rung::new("paths 32", &["--paths", "32"], &[]),
        Rung::new("paths 128", &["--paths", "128"], &[]),
        Rung::new("paths 64 MS scale 1", &["--multiple-scale", "1"], &[]),
        Rung::new("paths 64 MS scale 3", &["--multiple-scale", "3"], &[]),
        Rung::new("paths 64 MS scale 4", &["--multiple-scale", "4"], &[]),
        Rung::new("single scale 2", &["--cache-scale", "2"], &[]),
        // The shadows as they were traced before the tabled transmittance.
        Rung::new("shadow rays", &["--shadows", "rays"], &[]),
        Rung::new("spp 1", &[], &["--spp", "1"]),
        Rung::new("spp 16", &[], &["--spp", "16"]),
        Rung::new("step x2", &[], &["--step-factor", "2"]),
    ]);
    rungs.extend([
        Rung::photons("photons 200k", 200_000, "delta", 64),
        Rung::photons("photons 800k", 800_000, "delta", 64),
        // The neighbour count grows with the photons, as the measured optimum does (K 64 at
        // 200k, 128-256 at 3.2-12.8M).
        Rung::photons("photons 3.2M", 3_200_000, "delta", 128),
        Rung::photons("photons 12.8M", 12_800_000, "delta", 256),
        Rung::photons("exponential 50k", 50_000, "exponential", 64),
        Rung::photons("simpson 200k", 200_000, "simpson", 64),
        Rung::photons("simpson 800k", 800_000, "simpson", 64),
    ]);
    rungs
}

/// One measured rung.
#[derive(Clone, Debug)]
pub struct Row {
    pub scene: &'static str,
    pub rung: Rung,
    pub photon_s: f64,
    pub cache_s: f64,
    pub march_s: f64,
    /// CPU seconds (user + system) of the rung's tools.
    pub cpu_s: f64,
    pub relative_rmse: f64,
    /// The reference's own noise taken out in quadrature (its RMSE estimated from the
    /// spp/4 render: e(spp/4)^2 = 5 sigma(spp)^2 for independent 1/sqrt(spp) noise).
    pub corrected_rmse: f64,
    pub mean_ratio: f64,
    pub pareto: bool,
    /// For a rung whose photons are not delta-tracked (another distance mode, or paths instead
    /// of photons): the error the delta-tracked photon chain reaches in the same total time,
    /// read off the scene's delta-tracked Pareto front (log-log
    /// interpolation between its neighbours in time; `None` outside the front's time span or
    /// for delta rungs). The paper's Eq. 1 and Eq. 2 compared at equal time, as issue 7 asks.
    pub delta_rmse_at_equal_time: Option<f64>,
}

impl Row {
    pub fn total_s(&self) -> f64 {
        self.photon_s + self.cache_s + self.march_s
    }
}

/// CPU seconds (user + system) of this process's waited-for children so far, from
/// /proc/self/stat (cutime, cstime in clock ticks of 1/100 s: Linux's USER_HZ).
fn children_cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name, which is in parentheses and may hold spaces.
    let rest = stat.rsplit_once(')').map_or("", |r| r.1);
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| fields.get(i).and_then(|f| f.parse::<f64>().ok()).unwrap_or(0.0);
    // cutime and cstime are fields 16 and 17 of stat(5); the first field after the name is
    // the state, field 3, so they are the 14th and 15th after it (indices 13 and 14).
    (tick(13) + tick(14)) / 100.0
}

/// Runs a tool, returning its wall-clock and CPU seconds; its stderr goes to `log`.
fn run_tool(bin: &Path, tool: &str, args: &[String], log: &Path) -> Result<(f64, f64)> {
    let cpu_before = children_cpu_s();
    let start = Instant::now();
    let stderr = std::fs::File::create(log)?;
    let status = Command::new(bin.join(tool))
        .args(args)
        .stderr(stderr)
        .status()
        .with_context(|| format!("running {} (build the tools first: make build)", bin.join(tool).display()))?;
    let seconds = start.elapsed().as_secs_f64();
    if !status.success() {
        bail!("{tool} {} failed ({status}); see {}", args.join(" "), log.display());
    }
    Ok((seconds, children_cpu_s() - cpu_before))
}

/// Runs `vdbmarch args -o out` unless `out` is newer than `density` and `key_file` holds the
/// same command line; returns the seconds it took when it ran (`starting` is called first).
fn render_cached(bin: &Path, args: &[String], out: &Path, key_file: &Path, density: &Path, log: &Path, starting: impl FnOnce()) -> Result<Option<f64>> {
    let key = args.join(" ");
    if is_fresh(out, &[density]) && std::fs::read_to_string(key_file).ok().as_deref() == Some(key.as_str()) {
        return Ok(None);
    }
    starting();
    let mut a = args.to_vec();
    a.extend(["-o".into(), out.display().to_string()]);
    let (s, _) = run_tool(bin, "vdbmarch", &a, log)?;
    std::fs::write(key_file, &key)?;
    Ok(Some(s))
}

fn strings(a: &[&str]) -> Vec<String> {
    a.iter().map(|s| s.to_string()).collect()
}

fn is_fresh(output: &Path, inputs: &[&Path]) -> bool {
    let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    match modified(output) {
        Some(out) => inputs.iter().all(|i| modified(i).is_some_and(|t| t <= out)),
        None => false,
    }
}

/// Runs the ladder on every scene asked for.
pub fn run(args: &Args) -> Result<Vec<Row>> {
    let mut rows = Vec::new();
    for scene in SCENES.iter().filter(|s| args.scenes.is_empty() || args.scenes.iter().any(|n| n == s.name)) {
        rows.extend(run_scene(args, scene)?);
    }
    mark_pareto(&mut rows);
    mark_delta_at_equal_time(&mut rows);
    print_table(&rows);
    Ok(rows)
}

fn run_scene(args: &Args, scene: &Scene) -> Result<Vec<Row>> {
    let dir = args.out.join(scene.name);
    std::fs::create_dir_all(&dir)?;
    let path = |name: &str| -> PathBuf { dir.join(name) };
    let size = strings(&["--width", &args.width.to_string(), "--height", &args.height.to_string()]);
    let camera: Vec<String> = strings(scene.camera).into_iter().chain(size.clone()).collect();

    // The density, once.
    let density = path("density.vdb");
    if !is_fresh(&density, &[Path::new(scene.particles)]) {
        let mut a = vec![scene.particles.to_string()];
        a.extend(strings(scene.density));
        a.extend(["-o".into(), density.display().to_string()]);
        let (s, _) = run_tool(&args.bin, "particles2vdb", &a, &path("density.log"))?;
        eprintln!("{}: density in {s:.1} s", scene.name);
    }

    // The reference, cached under its command line.
    let reference = path("reference.exr");
    let mut ref_args = vec!["--reference".to_string(), density.display().to_string()];
    ref_args.extend(strings(scene.optics));
    ref_args.extend(camera.clone());
    let mut a = ref_args.clone();
    a.extend(["--spp".into(), args.reference_spp.to_string()]);
    let rendering = || eprintln!("{}: rendering the reference ({}x{}, {} spp)...", scene.name, args.width, args.height, args.reference_spp);
    if let Some(s) = render_cached(&args.bin, &a, &reference, &path("reference.key"), &density, &path("reference.log"), rendering)? {
        eprintln!("{}: reference in {s:.1} s", scene.name);
    }
    let reference_image = read(&reference)?;

    // The reference converges: at spp/16 and spp/4 (other seeds) against itself. These are
    // cached like the reference (at 8192 spp they cost a third of it again).
    let mut errors = Vec::new();
    for div in [16, 4] {
        let spp = (args.reference_spp / div).max(1);
        let out = path(&format!("reference-{spp}.exr"));
        let mut a = ref_args.clone();
        a.extend(["--spp".into(), spp.to_string(), "--seed".into(), (1000 + div).to_string()]);
        if let Some(s) = render_cached(&args.bin, &a, &out, &path(&format!("reference-{spp}.key")), &density, &path("reference-low.log"), || ())? {
            eprintln!("{}: reference at {spp} spp in {s:.1} s", scene.name);
        }
        let e = compare(&read(&out)?, &reference_image);
        eprintln!("{}: reference at {spp} spp: relative RMSE {:.4} against {} spp", scene.name, e.relative_rmse, args.reference_spp);
        errors.push(e.relative_rmse);
    }
    let reference_noise = errors[1] / 5f64.sqrt();
    eprintln!("{}: the reference's own relative RMSE is about {reference_noise:.4}", scene.name);
    eprintln!(
        "{}: quadrupling paths divides the reference's error by {:.2} (1/sqrt(spp): 2; the {}-spp stand-in's own noise lowers it)",
        scene.name,
        errors[0] / errors[1],
        args.reference_spp
    );

    // The ladder, each stage run once per distinct input.
    let mut photon_runs: HashMap<(u64, &str), (PathBuf, f64, f64)> = HashMap::new();
    let mut cache_runs: HashMap<String, (PathBuf, f64, f64)> = HashMap::new();
    let mut rows = Vec::new();
    let default_step = scene.voxel * 3f64.sqrt() / 3.0;
    for rung in ladder(args.quick) {
        let (input, photon_s, photon_cpu) = match rung.photons {
            None => (density.clone(), 0.0, 0.0),
            Some((photons, distance)) => {
                let pkey = (photons, distance);
                if !photon_runs.contains_key(&pkey) {
                    let out = path(&format!("photons-{photons}-{distance}.vdb"));
                    let mut a = vec![density.display().to_string()];
                    a.extend(strings(scene.optics));
                    a.extend(["--photons".into(), photons.to_string(), "--distance".into(), distance.into()]);
                    a.extend(["-o".into(), out.display().to_string()]);
                    let (s, cpu) = run_tool(&args.bin, "vdbphoton", &a, &path("vdbphoton.log"))?;
                    photon_runs.insert(pkey, (out, s, cpu));
                }
                photon_runs[&pkey].clone()
            }
        };
        let ckey = format!("{}-{}", rung.photons.map_or("paths".to_string(), |(n, d)| format!("{n}-{d}")), rung.cache.join("_").replace("--", ""));
        if !cache_runs.contains_key(&ckey) {
            let out = path(&format!("cache-{ckey}.vdb"));
            let mut a = vec![input.display().to_string()];
            a.extend(camera.clone());
            if rung.photons.is_none() {
                // Straight from the density: the optics vdbphoton would have recorded.
                a.extend(strings(scene.optics));
            }
            a.extend(rung.cache.iter().cloned());
            a.extend(["-o".into(), out.display().to_string()]);
            let (s, cpu) = run_tool(&args.bin, "vdbcache", &a, &path("vdbcache.log"))?;
            cache_runs.insert(ckey.clone(), (out, s, cpu));
        }
        let (cache, cache_s, cache_cpu) = cache_runs[&ckey].clone();
        let image = path(&format!("image-{}.exr", rung.name.replace(' ', "-")));
        let mut a = vec![cache.display().to_string()];
        // --step-factor is the bench's own: a multiple of the default step.
        let mut flags = rung.march.iter();
        while let Some(f) = flags.next() {
            match f.as_str() {
                "--step-factor" => {
                    let factor: f64 = flags.next().and_then(|v| v.parse().ok()).context("--step-factor takes a number")?;
                    a.extend(["--step".into(), (default_step * factor).to_string()]);
                }
                _ => a.push(f.clone()),
            }
        }
        a.extend(["-o".into(), image.display().to_string()]);
        let (march_s, march_cpu) = run_tool(&args.bin, "vdbmarch", &a, &path("vdbmarch.log"))?;
        let e = compare(&read(&image)?, &reference_image);
        let corrected_rmse = (e.relative_rmse.powi(2) - reference_noise.powi(2)).max(0.0).sqrt();
        let row = Row {
            scene: scene.name,
            rung,
            photon_s,
            cache_s,
            march_s,
            cpu_s: photon_cpu + cache_cpu + march_cpu,
            relative_rmse: e.relative_rmse,
            corrected_rmse,
            mean_ratio: e.mean_ratio,
            pareto: false,
            delta_rmse_at_equal_time: None,
        };
        eprintln!(
            "{}: {:<20} {:>7.2} s ({:.2} CPU s)  rel. RMSE {:.4} ({:.4} less the reference's noise)  mean ratio {:.3}",
            scene.name,
            row.rung.name,
            row.total_s(),
            row.cpu_s,
            row.relative_rmse,
            row.corrected_rmse,
            row.mean_ratio
        );
        rows.push(row);
    }
    Ok(rows)
}

/// Marks, per scene, the rungs no other rung beats in both total time and error.
fn mark_pareto(rows: &mut [Row]) {
    let snapshot = rows.to_vec();
    for row in rows.iter_mut() {
        row.pareto = !snapshot.iter().any(|o| o.scene == row.scene && dominates(o, row));
    }
}

/// `a` is at least as fast and as accurate as `b`, and strictly better in one.
fn dominates(a: &Row, b: &Row) -> bool {
    a.total_s() <= b.total_s()
        && a.relative_rmse <= b.relative_rmse
        && (a.total_s() < b.total_s() || a.relative_rmse < b.relative_rmse)
}

/// Fills [`Row::delta_rmse_at_equal_time`] for the rungs that do not delta-track.
fn mark_delta_at_equal_time(rows: &mut [Row]) {
    let snapshot = rows.to_vec();
    for row in rows.iter_mut().filter(|r| r.rung.distance() != "delta") {
        // The delta rungs no other delta rung of the scene beats in time and error, by time.
        let delta: Vec<&Row> = snapshot.iter().filter(|o| o.scene == row.scene && o.rung.distance() == "delta").collect();
        let mut front: Vec<(f64, f64)> = delta
            .iter()
            .filter(|o| !delta.iter().any(|d| dominates(d, o)))
            .map(|o| (o.total_s(), o.relative_rmse))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        row.delta_rmse_at_equal_time = interpolate_log_log(&front, row.total_s());
    }
}

/// y at x on the polyline through `points` (sorted by x) in log-log space; `None` outside it.
fn interpolate_log_log(points: &[(f64, f64)], x: f64) -> Option<f64> {
    let (first, last) = (points.first()?, points.last()?);
    if x < first.0 || x > last.0 {
        return None;
    }
    let i = points.partition_point(|p| p.0 < x).max(1).min(points.len() - 1);
    let ((x0, y0), (x1, y1)) = (points[i - 1], points[i]);
    if x1 <= x0 {
        return Some(y1);
    }
    let t = (x.ln() - x0.ln()) / (x1.ln() - x0.ln());
    Some((y0.ln() + t * (y1.ln() - y0.ln())).exp())
}

/// The table's columns: (CSV name, Markdown heading).
const COLUMNS: [(&str, &str); 15] = [
    ("scene", "scene"),
    ("rung", "rung"),
    ("photons", "photons"),
    ("distance", "distance"),
    ("vdbcache_flags", "vdbcache flags"),
    ("vdbmarch_flags", "vdbmarch flags"),
    ("photon_s", "vdbphoton s"),
    ("cache_s", "vdbcache s"),
    ("march_s", "vdbmarch s"),
    ("total_s", "total s"),
    ("cpu_s", "CPU s"),
    ("relative_rmse", "rel. RMSE"),
    ("corrected_rmse", "less ref. noise"),
    ("mean_ratio", "mean ratio"),
    ("pareto", "Pareto"),
];

/// A row's values in [`COLUMNS`] order, and the delta photons' error at equal time.
fn fields(r: &Row) -> Vec<String> {
    let g = &r.rung;
    vec![
        r.scene.to_string(),
        g.name.clone(),
        g.photons.map_or(String::new(), |p| p.0.to_string()),
        g.distance().to_string(),
        g.cache.join(" "),
        g.march.join(" "),
        format!("{:.2}", r.photon_s),
        format!("{:.2}", r.cache_s),
        format!("{:.2}", r.march_s),
        format!("{:.2}", r.total_s()),
        format!("{:.2}", r.cpu_s),
        format!("{:.4}", r.relative_rmse),
        format!("{:.4}", r.corrected_rmse),
        format!("{:.4}", r.mean_ratio),
        r.pareto.to_string(),
    ]
}

/// The delta-tracked photon chain's error at the rung's time, where it is measured.
fn delta_field(r: &Row) -> String {
    r.delta_rmse_at_equal_time.map_or(String::new(), |e| format!("{e:.4}"))
}

pub fn to_csv(rows: &[Row]) -> String {
    let mut out = COLUMNS.map(|c| c.0).join(",") + ",delta_rmse_at_equal_time\n";
    for r in rows {
        // Flags hold spaces, not commas.
        out += &(fields(r).join(",") + "," + &delta_field(r) + "\n");
    }
    out
}

fn print_table(rows: &[Row]) {
    println!("| {} | delta photons at equal time |", COLUMNS.map(|c| c.1).join(" | "));
    println!("|{}", "---|".repeat(COLUMNS.len() + 1));
    for r in rows {
        println!("| {} | {} |", fields(r).join(" | "), delta_field(r));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(scene: &'static str, t: f64, e: f64) -> Row {
        Row {
            scene,
            rung: Rung::photons("delta photons", 200_000, "delta", 64),
            photon_s: t,
            cache_s: 0.0,
            march_s: 0.0,
            cpu_s: t,
            relative_rmse: e,
            corrected_rmse: e,
            mean_ratio: 1.0,
            pareto: false,
            delta_rmse_at_equal_time: None,
        }
    }

    #[test]
    fn other_distance_modes_are_scored_against_the_delta_front_at_their_time() {
        let mut simpson = row("a", 4.0, 0.3);
        simpson.rung.photons = Some((200_000, "simpson"));
        let mut late = row("a", 100.0, 0.05);
        late.rung.photons = Some((200_000, "simpson"));
        // Delta front at 1 s / 0.4 and 16 s / 0.1 (the 8 s / 0.5 rung is dominated).
        let mut rows = vec![row("a", 1.0, 0.4), row("a", 8.0, 0.5), row("a", 16.0, 0.1), simpson, late, row("b", 4.0, 0.01)];
        mark_delta_at_equal_time(&mut rows);
        // Halfway in log time between 1 and 16 s: the geometric mean of 0.4 and 0.1.
        let at4 = rows[3].delta_rmse_at_equal_time.unwrap();
        assert!((at4 - 0.2).abs() < 1e-12, "{at4}");
        assert_eq!(rows[4].delta_rmse_at_equal_time, None, "beyond the front's time span");
        assert!(rows.iter().filter(|r| r.rung.distance() == "delta").all(|r| r.delta_rmse_at_equal_time.is_none()));
    }

    #[test]
    fn the_pareto_front_keeps_only_undominated_rungs_per_scene() {
        let mut rows = vec![row("a", 1.0, 0.5), row("a", 2.0, 0.2), row("a", 3.0, 0.3), row("a", 2.0, 0.2), row("b", 9.0, 0.9)];
        mark_pareto(&mut rows);
        let marks: Vec<bool> = rows.iter().map(|r| r.pareto).collect();
        assert_eq!(marks, [true, true, false, true, true]);
    }

    #[test]
    fn csv_has_one_line_per_row_and_the_header() {
        let csv = to_csv(&[row("a", 1.0, 0.5)]);
        assert_eq!(csv.lines().count(), 2);
        assert_eq!(csv.lines().next().unwrap().split(',').count(), csv.lines().nth(1).unwrap().split(',').count());
    }
}
