//! How the command shows the Hub client's downloads (`hub::HubEvent`): a bar per large file on
//! a terminal, a line every few seconds in a log, warnings as warnings. The client itself
//! draws nothing; this is its front end's view.

use std::collections::HashMap;
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

use crate::hub::{EventSink, HubEvent, HubSettings};
use crate::units::human_bytes;

/// Seconds between a file's progress lines when stderr is not a terminal.
const LINE_EVERY: Duration = Duration::from_secs(5);

/// One file being downloaded, as shown.
enum Shown {
    Bar(ProgressBar),
    Lines { last: Instant },
}

/// `settings` with the command's view of its downloads attached.
pub fn on_stderr(settings: HubSettings) -> HubSettings {
    let terminal = std::io::stderr().is_terminal();
    let shown: Mutex<HashMap<String, Shown>> = Mutex::new(HashMap::new());
    let sink = EventSink::new(move |event| {
        let mut shown = shown.lock().unwrap_or_else(|p| p.into_inner());
        show(&mut shown, terminal, event);
    });
    HubSettings {
        on_event: Some(sink),
        ..settings
    }
}

fn show(shown: &mut HashMap<String, Shown>, terminal: bool, event: &HubEvent) {
    match event {
        HubEvent::Started { file, total } => {
            let view = if terminal {
                let bar = ProgressBar::new(total.unwrap_or(0));
                if let Ok(style) = ProgressStyle::with_template(
                    "{msg} [{bar:30}] {bytes}/{total_bytes} {bytes_per_sec} {eta}",
                ) {
                    bar.set_style(style.progress_chars("=> "));
                }
                bar.set_message(file.clone());
                Shown::Bar(bar)
            } else {
                let size = total.map_or("unknown size".into(), |t| human_bytes(t as u128));
                errln!("downloading {file} ({size})");
                Shown::Lines {
                    last: Instant::now(),
                }
            };
            shown.insert(file.clone(), view);
        }
        HubEvent::Progress { file, done, total } => match shown.get_mut(file) {
            Some(Shown::Bar(bar)) => {
                if let Some(t) = total {
                    bar.set_length(*t);
                }
                bar.set_position(*done);
            }
            Some(Shown::Lines { last }) if last.elapsed() >= LINE_EVERY => {
                *last = Instant::now();
                let of = total.map_or(String::new(), |t| format!(" of {}", human_bytes(t as u128)));
                errln!("{file}: {}{of}", human_bytes(*done as u128));
            }
            _ => {}
        },
        HubEvent::Finished { file, done, ok } => match shown.remove(file) {
            Some(Shown::Bar(bar)) if *ok => bar.finish(),
            Some(Shown::Bar(bar)) => bar.abandon(),
            Some(Shown::Lines { .. }) => {
                let how = if *ok { "downloaded" } else { "stopped" };
                errln!("{file}: {how} ({})", human_bytes(*done as u128));
            }
            None => {}
        },
        HubEvent::Warning(w) => errln!("t2tf: warning: {w}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_gets_a_start_and_an_end_line_and_forgets_the_file() {
        let mut shown = HashMap::new();
        let file = "model.safetensors".to_string();
        show(
            &mut shown,
            false,
            &HubEvent::Started {
                file: file.clone(),
                total: Some(600 << 20),
            },
        );
        assert!(matches!(shown.get(&file), Some(Shown::Lines { .. })));
        show(
            &mut shown,
            false,
            &HubEvent::Finished {
                file: file.clone(),
                done: 600 << 20,
                ok: true,
            },
        );
        assert!(shown.is_empty());
    }
}
