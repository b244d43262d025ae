//! A 12-frame drag of the real chest CT through the viewer, 5° a frame, with `cull=verified`:
//! the bricks each frame renders and repairs when it predicts from the client's last frame
//! (`previous`) and when it predicts with the proxy (a new client each frame), and the
//! threshold rule for both against the unculled frame. Ignored unless run with
//! `--ignored`: it needs the catalogue's volumes (`POFVR_DATA`, or `shared/data` beside the
//! repository). Run with `--nocapture` for the table.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use common::{assert_rule, frame};
use pofvr::{Scene, TransferFunction, Volume};
use pofvr_web::{Viewer, ViewerOptions};

fn shared_data() -> Option<PathBuf> {
    let dir = match std::env::var_os("POFVR_DATA") {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    };
    dir.join("CATALOG.md").is_file().then_some(dir)
}

#[tokio::test]
#[ignore = "needs the real volumes (POFVR_DATA)"]
async fn a_drag_of_the_chest_ct_renders_fewer_bricks_from_the_previous_frame() {
    let Some(data) = shared_data() else {
        println!("skipped: no CATALOG.md in POFVR_DATA or ../shared/data");
        return;
    };
    let vol = Volume::open(&data.join("lidc2_ct_chest/lidc2_ct_chest.nhdr"), None).unwrap();
    let family = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tfs/ct-chest-skin-bone.json");
    let tf = TransferFunction::from_file(&family).unwrap();
    // As `pofvr serve` builds it: bricks of 16.
    let scene = Scene::builder(vol, tf).brick_size(16).build().unwrap();
    let v = Arc::new(Viewer::new(
        Arc::new(scene),
        "lidc2_ct_chest",
        &ViewerOptions::default(),
    ));
    // The family's own look, and an opaque skin (where the prediction has more to cull).
    for (w, weights) in [(0, "1,1"), (1, "8,1")] {
        let look = format!("w=512&h=512&el=20&threshold=0.95&weights={weights}");
        println!(
            "frame az  | previous: predictor rendered repaired | proxy: rendered repaired | exact | non-empty"
        );
        let (mut prev_sum, mut proxy_sum, mut prev_rep, mut proxy_rep, mut exact_sum) =
            (0, 0, 0, 0, 0);
        for k in 0..12u32 {
            let az = 30 + 5 * k;
            let (a, dragged) =
                frame(&v, &format!("{look}&az={az}&cull=verified&client=drag{w}")).await;
            let (b, proxied) = frame(
                &v,
                &format!("{look}&az={az}&cull=verified&client=fresh{w}{k}"),
            )
            .await;
            let (e, _) = frame(&v, &format!("{look}&az={az}&cull=exact&client=exact")).await;
            let (_, unculled) = frame(&v, &format!("{look}&az={az}&cull=none&client=none")).await;
            assert_eq!(b["predictor"], "proxy");
            assert_eq!(
                a["predictor"],
                if k == 0 { "proxy" } else { "previous" },
                "frame {k}"
            );
            assert_rule(&unculled, &dragged, 0.95, &format!("previous, frame {k}"));
            assert_rule(&unculled, &proxied, 0.95, &format!("proxy, frame {k}"));
            let n = |s: &serde_json::Value, f: &str| s["bricks"][f].as_u64().unwrap();
            println!(
                "{weights:>5} {k:>5} {az:>3} | {:>8} {:>8} {:>8} | {:>8} {:>8} | {:>5} | {}",
                a["predictor"].as_str().unwrap(),
                n(&a, "visible"),
                n(&a, "repaired"),
                n(&b, "visible"),
                n(&b, "repaired"),
                n(&e, "visible"),
                n(&a, "non_empty")
            );
            if k > 0 {
                prev_sum += n(&a, "visible");
                prev_rep += n(&a, "repaired");
                proxy_sum += n(&b, "visible");
                proxy_rep += n(&b, "repaired");
                exact_sum += n(&e, "visible");
            }
        }
        println!(
            "weights {weights}, frames 1-11: previous renders {:.1} bricks/frame ({:.1} repaired), proxy {:.1} ({:.1} repaired), exact {:.1}",
            prev_sum as f64 / 11.0,
            prev_rep as f64 / 11.0,
            proxy_sum as f64 / 11.0,
            proxy_rep as f64 / 11.0,
            exact_sum as f64 / 11.0
        );
    }
}
