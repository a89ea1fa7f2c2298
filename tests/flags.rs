//! Scene flags travel down the chain (issue #47, design.md section 6): medium, lights,
//! environment, camera, emission, temperature and seed given to the first tool reach every
//! later tool through the file's record, and give the same final EXR, pixels and header byte
//! for byte, as the same flags given to every tool. A later tool's own recognition of a fire
//! never overrides an explicit choice recorded upstream; `-v` says where each setting came
//! from. The input is Blender's Mantaflow fire (data/fire.vdb: `density`, `flame` and
//! Mantaflow's normalised `temperature`), which vdbmarch would otherwise recognise as a fire.

mod common;

use common::{exr_attribute, pipe_ok};

fn fire() -> Vec<u8> {
    std::fs::read(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/fire.vdb")).unwrap()
}

/// What every chain is given on its first tool, whatever the group: a small image and the
/// draft preset's paths, so each chain takes a second.
const BASE: &[&str] = &["--width", "24", "--height", "32", "--device", "cpu"];
const MARCH: &[&str] = &["--device", "cpu", "--quality", "draft"];

/// One group of flags each: all of a kind a user gives together.
const GROUPS: &[(&str, &[&str])] = &[
    ("medium", &["--extinction", "3", "--albedo", "0.7,0.8,0.9", "--g", "0.4"]),
    ("lights", &["--sun", "dir=0.3,0.2,-0.9,irradiance=5", "--point", "pos=1,-3,2,intensity=4"]),
    ("environment", &["--sky", "0.1,0.2,0.3"]),
    ("camera", &["--eye", "0.2,-6,1.3", "--look-at", "0,0,1", "--fov", "28", "--up", "0,0,1"]),
    ("emission", &["--emission-grid", "flame", "--emission-strength", "5", "--emission-color", "1,0.5,0.2"]),
    ("temperature", &["--temperature-grid", "temperature", "--temperature-scale", "800", "--blackbody-intensity", "0.5"]),
    ("no emission", &["--no-emission"]),
    ("seed", &["--seed", "9"]),
];

/// `vdbcache BASE GROUP | vdbmarch [GROUP]`: the final EXR's bytes and vdbmarch's stderr.
fn chain(group: &[&str], on_march: bool, extra_march: &[&str]) -> (Vec<u8>, String) {
    let cache = pipe_ok("vdbcache", &[BASE, &["--quality", "draft"], group].concat(), &fire());
    let march_flags = [MARCH, extra_march, if on_march { group } else { &[] }].concat();
    let march = pipe_ok("vdbmarch", &march_flags, &cache.stdout);
    (march.stdout, String::from_utf8_lossy(&march.stderr).into_owned())
}

#[test]
fn flags_on_the_first_tool_give_the_image_of_flags_on_every_tool() {
    let (plain, _) = chain(&[], false, &[]);
    for (name, group) in GROUPS {
        let (first_only, log) = chain(group, false, &["-v"]);
        let (everywhere, _) = chain(group, true, &["-v"]);
        assert!(first_only == everywhere, "{name}: flags on vdbcache alone give another EXR than on every tool ({})", {
            let a = exr_attribute(&first_only, "nimbus:emission");
            let b = exr_attribute(&everywhere, "nimbus:emission");
            format!("emission {a:?} against {b:?}")
        });
        // Each group changes the image, so the comparison above could fail.
        assert!(first_only != plain, "{name}: the flags change nothing, so the test shows nothing");
        match *name {
            "emission" => {
                assert!(!log.contains("recognised"), "{name}: the recognition overrode the recorded flags: {log}");
                assert!(log.contains("emission: grid=flame,strength=5,color=1,0.5,0.2 (the input's record)"), "{log}");
                assert_eq!(exr_attribute(&first_only, "nimbus:emission").as_deref(), Some("grid=flame,strength=5,color=1,0.5,0.2"));
            }
            "temperature" => {
                assert!(!log.contains("recognised"), "{name}: {log}");
                assert_eq!(exr_attribute(&first_only, "nimbus:emission").as_deref(), Some("temperature=temperature,scale=800,blackbody=0.5"));
            }
            "no emission" => assert_eq!(exr_attribute(&first_only, "nimbus:emission").as_deref(), Some("none")),
            "medium" => assert!(log.contains("medium: ") && log.contains("(the input's record)"), "{log}"),
            _ => {}
        }
    }
    // Without flags the Mantaflow fire is recognised, as before.
    let (_, log) = chain(&[], false, &["-v"]);
    assert!(log.contains("recognised a Blender Mantaflow fire"), "{log}");
}

/// A flag given again later wins over the record, and -v says so.
#[test]
fn a_later_flag_wins_over_the_record() {
    let emission = ["--emission-grid", "flame", "--emission-strength", "5"];
    let (recorded, _) = chain(&emission, false, &[]);
    let (overridden, log) = chain(&emission, false, &["-v", "--emission-strength", "2"]);
    assert!(recorded != overridden);
    assert!(log.contains("emission: grid=flame,strength=2,color=1,1,1 (flags over the input's record)"), "{log}");
    assert_eq!(exr_attribute(&overridden, "nimbus:emission").as_deref(), Some("grid=flame,strength=2,color=1,1,1"));
}

/// vdbphoton first: its flags reach vdbcache and vdbmarch through the photon file.
#[test]
fn flags_travel_from_vdbphoton() {
    let group: &[&str] = &["--emission-grid", "flame", "--emission-strength", "5", "--albedo", "0.6", "--sun", "dir=0,0.3,-1,irradiance=3"];
    let photons: &[&str] = &["--photons", "2000", "--device", "cpu"];
    let run = |everywhere: bool| {
        let later = if everywhere { group } else { &[] };
        let p = pipe_ok("vdbphoton", &[photons, group].concat(), &fire());
        let c = pipe_ok("vdbcache", &[BASE, &["--quality", "draft"], later].concat(), &p.stdout);
        pipe_ok("vdbmarch", &[MARCH, later].concat(), &c.stdout).stdout
    };
    let first_only = run(false);
    assert!(first_only == run(true), "flags on vdbphoton alone give another EXR than on every tool");
    assert_eq!(exr_attribute(&first_only, "nimbus:emission").as_deref(), Some("grid=flame,strength=5,color=1,1,1"));
}
