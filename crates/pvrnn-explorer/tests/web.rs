//! The explorer's browser glue, in headless Chromium:
//! `CHROMEDRIVER=/usr/bin/chromedriver cargo test -p pvrnn-explorer --target wasm32-unknown-unknown`
//! (scripts/test.sh). The whole site is tested by tests/web/smoke.mjs.
#![cfg(target_arch = "wasm32")]

use pvrnn_explorer::engine::{CompactStep, Event, Finished, ModuleStep, StepLayout};
use pvrnn_explorer::runs::{Condition, RunKey};
use pvrnn_explorer::worker::{event_from_message, event_message};
use wasm_bindgen_test::{wasm_bindgen_test, wasm_bindgen_test_configure};
use web_time::Duration;

wasm_bindgen_test_configure!(run_in_browser);

fn key() -> RunKey {
    RunKey {
        sequence: "wiping_650mm_test0".into(),
        condition: Condition {
            vision_levels: 1,
            proprio: true,
            ablation: [false, true, false, false],
            window: 30,
            iterations: 50,
            lr_milli: 90,
            seed: 3,
        },
    }
}

#[wasm_bindgen_test]
fn worker_messages_round_trip() {
    let layout = StepLayout {
        z: [1, 2, 1, 1],
        d: [2, 3, 2, 2],
        proprio: 3,
    };
    let mut n = 0.0f32;
    let mut next = |len: usize| {
        (0..len)
            .map(|_| {
                n += 0.25;
                n
            })
            .collect::<Vec<f32>>()
    };
    let step = CompactStep {
        modules: std::array::from_fn(|m| ModuleStep {
            mu_p: next(layout.z[m]),
            sigma_p: next(layout.z[m]),
            mu_q: next(layout.z[m]),
            sigma_q: next(layout.z[m]),
            d: next(layout.d[m]),
            prior_d: next(layout.d[m]),
        }),
        free_energy: 12.5,
        recon_error: [0.01, 0.02],
        proprio_recon: next(3),
        proprio_prior: next(3),
    };
    let events = [
        Event::Step(key(), Box::new(step)),
        Event::Done(Finished {
            key: key(),
            steps: 300,
            busy: Duration::from_millis(1500),
            wall: Duration::from_millis(2000),
        }),
        Event::Failed(key(), "no observations".into()),
    ];
    for event in events {
        let (message, _transfer) = event_message(&event, 7);
        let back = event_from_message(&message, &layout).expect("decodes");
        assert_eq!(back, event);
    }
    // A step of another model's layout is refused with a message, not misread.
    let (message, _) = event_message(&Event::Step(key(), Box::default()), 7);
    let err = event_from_message(&message, &layout).unwrap_err();
    assert!(err.contains("numbers"), "{err}");
}

#[wasm_bindgen_test]
fn the_url_hash_round_trips() {
    pvrnn_explorer::web::set_hash("seq=wiping_650mm_test0&t=12&vision=1");
    assert_eq!(
        pvrnn_explorer::web::location_hash(),
        "#seq=wiping_650mm_test0&t=12&vision=1"
    );
}
