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

/// One rung of the ladder.
#[derive(Clone, Debug)]
pub struct Rung {
    pub name: String,
    pub photons: u64,
    pub distance: &'static str,
    pub neighbours: u32,
    pub cache_scale: f64,
    /// March step over the default (a third of a voxel diagonal).
    pub step_factor: f64,
    pub spp: u32,
    /// `vdbcache --paths`: multiple scattering by this many paths per cache voxel instead of
    /// photons (then `photons` is 0 and vdbphoton is not run); 0 for photons.
    pub paths: u32,
    /// `vdbcache --multiple-scale` (None: the cache scale).
    pub multiple_scale: Option<f64>,
}

impl Rung {
    fn new(name: &str, photons: u64, distance: &'static str, neighbours: u32, cache_scale: f64, step_factor: f64, spp: u32) -> Rung {
        Rung { name: name.into(), photons, distance, neighbours, cache_scale, step_factor, spp, paths: 0, multiple_scale: None }
    }

    /// The chain without photons: vdbcache traces `paths` per voxel on a Li_multiple lattice
    /// `multiple_scale` density voxels wide.
    fn paths(name: &str, paths: u32, cache_scale: f64, multiple_scale: f64) -> Rung {
        Rung { paths, multiple_scale: Some(multiple_scale), ..Rung::new(name, 0, "none", 0, cache_scale, 1.0, 1) }
    }
}

/// The presets (`--quality`), as the tools apply them.
pub fn presets() -> Vec<Rung> {
    Quality::ALL
        .iter()
        .map(|q| {
            let s = q.settings();
            Rung { paths: s.paths, ..Rung::new(q.name(), 0, "none", 0, s.cache_scale, s.step_factor, s.spp) }
        })
        .collect()
}

/// The ladder: the presets, and one setting at a time varied around the tools' defaults
/// (200k photons, 64 neighbours, cache scale 2, default step, 1 spp), including the paper's
/// distance modes (they cost more per photon, so each is also scored against delta tracking
/// at equal time: [`Row::delta_rmse_at_equal_time`]), and two rungs far past the presets
/// that show what the error costs on its way to 2%.
fn ladder(quick: bool) -> Vec<Rung> {
    let p = Rung::new("", 200_000, "delta", 64, 2.0, 1.0, 1);
    let vary = |name: &str, f: &dyn Fn(&mut Rung)| {
        let mut r = p.clone();
        f(&mut r);
        r.name = name.into();
        r
    };
    let mut rungs = presets();
    if quick {
        rungs.truncate(2);
        return rungs;
    }
    rungs.extend([
        vary("photons 50k", &|r| r.photons = 50_000),
        vary("photons 200k", &|_| ()),
        vary("photons 800k", &|r| r.photons = 800_000),
        // Where the error goes with many more photons, and at what time: the neighbour count
        // grows with them, as the measured optimum does (K 64 at 200k, 128-256 at 3.2-12.8M).
        vary("photons 3.2M", &|r| {
            r.photons = 3_200_000;
            r.neighbours = 128
        }),
        vary("photons 12.8M", &|r| {
            r.photons = 12_800_000;
            r.neighbours = 256
        }),
        vary("exponential 50k", &|r| {
            r.photons = 50_000;
            r.distance = "exponential"
        }),
        vary("simpson 50k", &|r| {
            r.photons = 50_000;
            r.distance = "simpson"
        }),
        vary("simpson 200k", &|r| r.distance = "simpson"),
        vary("simpson 800k", &|r| {
            r.photons = 800_000;
            r.distance = "simpson"
        }),
        vary("delta 50k", &|r| r.photons = 50_000),
        vary("neighbours 16", &|r| r.neighbours = 16),
        vary("neighbours 256", &|r| r.neighbours = 256),
        vary("cache scale 1", &|r| r.cache_scale = 1.0),
        vary("cache scale 4", &|r| r.cache_scale = 4.0),
        vary("step x2", &|r| r.step_factor = 2.0),
        vary("step x0.5", &|r| r.step_factor = 0.5),
        vary("spp 4", &|r| r.spp = 4),
    ]);
    // Multiple scattering by paths from the cache voxels instead of photons: the paths per
    // voxel, on Li_multiple lattices 4 and 2 density voxels wide (single scattering keeps the
    // default cache scale 2).
    rungs.extend([
        Rung::paths("paths 16", 16, 2.0, 4.0),
        Rung::paths("paths 64", 64, 2.0, 4.0),
        Rung::paths("paths 256", 256, 2.0, 4.0),
        Rung::paths("paths 16 fine", 16, 2.0, 2.0),
        Rung::paths("paths 128 fine", 128, 2.0, 2.0),
    ]);
    // "delta 50k" repeats "photons 50k"; keep one.
    rungs.retain(|r| r.name != "delta 50k");
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

/// Runs a tool, returning its wall-clock seconds; its stderr goes to `log`.
fn run_tool(bin: &Path, tool: &str, args: &[String], log: &Path) -> Result<f64> {
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
    Ok(seconds)
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
    let s = run_tool(bin, "vdbmarch", &a, log)?;
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
        let s = run_tool(&args.bin, "particles2vdb", &a, &path("density.log"))?;
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
    let mut photon_runs: HashMap<(u64, &str), (PathBuf, f64)> = HashMap::new();
    let mut cache_runs: HashMap<String, (PathBuf, f64)> = HashMap::new();
    let mut rows = Vec::new();
    let default_step = scene.voxel * 3f64.sqrt() / 3.0;
    for rung in ladder(args.quick) {
        let (input, photon_s) = if rung.paths > 0 {
            (density.clone(), 0.0)
        } else {
            let pkey = (rung.photons, rung.distance);
            if !photon_runs.contains_key(&pkey) {
                let out = path(&format!("photons-{}-{}.vdb", rung.photons, rung.distance));
                let mut a = vec![density.display().to_string()];
                a.extend(strings(scene.optics));
                a.extend(["--photons".into(), rung.photons.to_string(), "--distance".into(), rung.distance.into()]);
                a.extend(["-o".into(), out.display().to_string()]);
                let s = run_tool(&args.bin, "vdbphoton", &a, &path("vdbphoton.log"))?;
                photon_runs.insert(pkey, (out, s));
            }
            photon_runs[&pkey].clone()
        };
        let ckey = match rung.multiple_scale {
            _ if rung.paths == 0 => format!("{}-{}-{}-{}", rung.photons, rung.distance, rung.neighbours, rung.cache_scale),
            ms => format!("paths-{}-{}-{}", rung.paths, rung.cache_scale, ms.unwrap_or(rung.cache_scale)),
        };
        if !cache_runs.contains_key(&ckey) {
            let out = path(&format!("cache-{ckey}.vdb"));
            let mut a = vec![input.display().to_string()];
            a.extend(camera.clone());
            a.extend(["--cache-scale".into(), rung.cache_scale.to_string()]);
            if rung.paths > 0 {
                // Straight from the density: the optics vdbphoton would have recorded.
                a.extend(strings(scene.optics));
                a.extend(["--paths".into(), rung.paths.to_string()]);
            } else {
                a.extend(["--gather-neighbours".into(), rung.neighbours.to_string()]);
            }
            if let Some(ms) = rung.multiple_scale {
                a.extend(["--multiple-scale".into(), ms.to_string()]);
            }
            a.extend(["-o".into(), out.display().to_string()]);
            let s = run_tool(&args.bin, "vdbcache", &a, &path("vdbcache.log"))?;
            cache_runs.insert(ckey.clone(), (out, s));
        }
        let (cache, cache_s) = cache_runs[&ckey].clone();
        let image = path(&format!("image-{}.exr", rung.name.replace(' ', "-")));
        let a = vec![
            cache.display().to_string(),
            "--step".into(),
            (default_step * rung.step_factor).to_string(),
            "--spp".into(),
            rung.spp.to_string(),
            "-o".into(),
            image.display().to_string(),
        ];
        let march_s = run_tool(&args.bin, "vdbmarch", &a, &path("vdbmarch.log"))?;
        let e = compare(&read(&image)?, &reference_image);
        let corrected_rmse = (e.relative_rmse.powi(2) - reference_noise.powi(2)).max(0.0).sqrt();
        let row = Row {
            scene: scene.name,
            rung,
            photon_s,
            cache_s,
            march_s,
            relative_rmse: e.relative_rmse,
            corrected_rmse,
            mean_ratio: e.mean_ratio,
            pareto: false,
            delta_rmse_at_equal_time: None,
        };
        eprintln!("{}: {:<16} {:>7.2} s  rel. RMSE {:.4} ({:.4} less the reference's noise)  mean ratio {:.3}", scene.name, row.rung.name, row.total_s(), row.relative_rmse, row.corrected_rmse, row.mean_ratio);
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
    for row in rows.iter_mut().filter(|r| r.rung.distance != "delta") {
        // The delta rungs no other delta rung of the scene beats in time and error, by time.
        let delta: Vec<&Row> = snapshot.iter().filter(|o| o.scene == row.scene && o.rung.distance == "delta").collect();
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
const COLUMNS: [(&str, &str); 19] = [
    ("scene", "scene"),
    ("rung", "rung"),
    ("photons", "photons"),
    ("distance", "distance"),
    ("neighbours", "K"),
    ("paths", "paths"),
    ("cache_scale", "cache scale"),
    ("multiple_scale", "MS scale"),
    ("step_factor", "step x"),
    ("spp", "spp"),
    ("photon_s", "vdbphoton s"),
    ("cache_s", "vdbcache s"),
    ("march_s", "vdbmarch s"),
    ("total_s", "total s"),
    ("relative_rmse", "rel. RMSE"),
    ("corrected_rmse", "less ref. noise"),
    ("mean_ratio", "mean ratio"),
    ("pareto", "Pareto"),
    ("delta_rmse_at_equal_time", "delta photons at equal time"),
];

/// A row's values in [`COLUMNS`] order.
fn fields(r: &Row) -> Vec<String> {
    let g = &r.rung;
    vec![
        r.scene.to_string(),
        g.name.clone(),
        g.photons.to_string(),
        g.distance.to_string(),
        g.neighbours.to_string(),
        g.paths.to_string(),
        g.cache_scale.to_string(),
        g.multiple_scale.unwrap_or(g.cache_scale).to_string(),
        g.step_factor.to_string(),
        g.spp.to_string(),
        format!("{:.2}", r.photon_s),
        format!("{:.2}", r.cache_s),
        format!("{:.2}", r.march_s),
        format!("{:.2}", r.total_s()),
        format!("{:.4}", r.relative_rmse),
        format!("{:.4}", r.corrected_rmse),
        format!("{:.4}", r.mean_ratio),
        r.pareto.to_string(),
        r.delta_rmse_at_equal_time.map_or(String::new(), |e| format!("{e:.4}")),
    ]
}

pub fn to_csv(rows: &[Row]) -> String {
    let mut out = COLUMNS.map(|c| c.0).join(",") + "\n";
    for r in rows {
        out += &(fields(r).join(",") + "\n");
    }
    out
}

fn print_table(rows: &[Row]) {
    println!("| {} |", COLUMNS.map(|c| c.1).join(" | "));
    println!("|{}", "---|".repeat(COLUMNS.len()));
    for r in rows {
        println!("| {} |", fields(r).join(" | "));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(scene: &'static str, t: f64, e: f64) -> Row {
        Row {
            scene,
            rung: Rung::new("delta photons", 200_000, "delta", 64, 2.0, 1.0, 1),
            photon_s: t,
            cache_s: 0.0,
            march_s: 0.0,
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
        simpson.rung.distance = "simpson";
        let mut late = row("a", 100.0, 0.05);
        late.rung.distance = "simpson";
        // Delta front at 1 s / 0.4 and 16 s / 0.1 (the 8 s / 0.5 rung is dominated).
        let mut rows = vec![row("a", 1.0, 0.4), row("a", 8.0, 0.5), row("a", 16.0, 0.1), simpson, late, row("b", 4.0, 0.01)];
        mark_delta_at_equal_time(&mut rows);
        // Halfway in log time between 1 and 16 s: the geometric mean of 0.4 and 0.1.
        let at4 = rows[3].delta_rmse_at_equal_time.unwrap();
        assert!((at4 - 0.2).abs() < 1e-12, "{at4}");
        assert_eq!(rows[4].delta_rmse_at_equal_time, None, "beyond the front's time span");
        assert!(rows.iter().filter(|r| r.rung.distance == "delta").all(|r| r.delta_rmse_at_equal_time.is_none()));
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
