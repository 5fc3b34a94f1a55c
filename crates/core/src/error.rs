use std::path::PathBuf;

/// Errors of the math core and its file formats.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CoreError {
    /// A number or setting outside its accepted range.
    #[error("invalid {what} {value} (expected {expected})")]
    Invalid {
        /// Which setting.
        what: String,
        /// The value given.
        value: String,
        /// The accepted range, with units.
        expected: String,
    },
    /// A computation that has no unique answer (parallel vectors, too few points...).
    #[error("degenerate geometry: {0}")]
    Degenerate(String),
    /// A file could not be read or written.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause (in the message, so not also a `source()`: error chains printed
        /// with their causes would repeat it).
        cause: std::io::Error,
    },
    /// A file was read but its content is not what we expected.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
}

impl CoreError {
    /// An out-of-range value, naming the setting and the accepted range.
    pub fn invalid(
        what: impl Into<String>,
        value: impl ToString,
        expected: impl Into<String>,
    ) -> Self {
        Self::Invalid {
            what: what.into(),
            value: value.to_string(),
            expected: expected.into(),
        }
    }

    /// An I/O error on a path.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            cause: source,
        }
    }

    /// A format error on a path.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.into(),
            message: message.into(),
        }
    }
}
