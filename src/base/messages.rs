//! What the library says to the person running it. Results (the terminal's
//! standard output) and notes and warnings (its standard error) go through
//! one sink, so that a caller that is not the terminal (a Python module, a
//! notebook, a service, a test) can capture or silence them; until a caller
//! installs a sink they are printed as a command-line tool prints them. The
//! engine and the pipeline never print themselves (`tests/it/layers.rs`
//! checks it): they use `messages::say!` and `messages::note!`.

use std::sync::{Arc, RwLock};

/// Which of the two streams a message belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// What the command was asked for: verdicts, tables, paths of outputs.
    Result,
    /// Progress notes and warnings.
    Note,
}

/// Receives every message of the library.
pub trait Sink: Send + Sync {
    fn emit(&self, channel: Channel, text: &str);
}

/// Results on stdout, notes on stderr.
pub struct Terminal;

impl Sink for Terminal {
    fn emit(&self, channel: Channel, text: &str) {
        match channel {
            Channel::Result => println!("{text}"),
            Channel::Note => eprintln!("{text}"),
        }
    }
}

/// Says nothing.
pub struct Quiet;

impl Sink for Quiet {
    fn emit(&self, _channel: Channel, _text: &str) {}
}

static SINK: RwLock<Option<Arc<dyn Sink>>> = RwLock::new(None);

/// Sends every later message to `sink` (for the whole process); returns the
/// one it replaces (`None`: the terminal).
pub fn set_sink(sink: Arc<dyn Sink>) -> Option<Arc<dyn Sink>> {
    match SINK.write() {
        Ok(mut slot) => slot.replace(sink),
        Err(poisoned) => poisoned.into_inner().replace(sink),
    }
}

/// One message to the installed sink, or the terminal.
pub fn emit(channel: Channel, text: &str) {
    let sink = SINK.read().ok().and_then(|slot| slot.clone());
    match sink {
        Some(sink) => sink.emit(channel, text),
        None => Terminal.emit(channel, text),
    }
}

/// A result line, formatted as `println!` would (see the module docs).
macro_rules! say {
    () => {
        $crate::base::messages::emit($crate::base::messages::Channel::Result, "")
    };
    ($($arg:tt)*) => {
        $crate::base::messages::emit($crate::base::messages::Channel::Result, &format!($($arg)*))
    };
}

/// A note or warning line, formatted as `eprintln!` would (see the module docs).
macro_rules! note {
    () => {
        $crate::base::messages::emit($crate::base::messages::Channel::Note, "")
    };
    ($($arg:tt)*) => {
        $crate::base::messages::emit($crate::base::messages::Channel::Note, &format!($($arg)*))
    };
}

pub(crate) use {note, say};
