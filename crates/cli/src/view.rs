//! `svbrdf view`: a local web page showing the glTF export in three.js, served from
//! the binary (page and three.js are embedded; nothing is fetched from the web).
//! Loopback only; a busy or unspecified port falls back to a free one.

use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;

#[derive(Args, Clone)]
pub struct ViewArgs {
    /// A run folder (holding export/gltf/material.gltf), or a folder holding
    /// material.gltf itself.
    pub dir: PathBuf,
    /// Port on 127.0.0.1 (default: any free port; a busy port falls back to a free one).
    #[arg(long)]
    pub port: Option<u16>,
}

/// Embedded files: (URL path, content type, bytes).
const ASSETS: &[(&str, &str, &[u8])] = &[
    (
        "/",
        "text/html; charset=utf-8",
        include_bytes!("../assets/viewer/index.html"),
    ),
    (
        "/three/three.module.min.js",
        "text/javascript",
        include_bytes!("../assets/three/three.module.min.js"),
    ),
    (
        "/three/loaders/GLTFLoader.js",
        "text/javascript",
        include_bytes!("../assets/three/loaders/GLTFLoader.js"),
    ),
    (
        "/three/utils/BufferGeometryUtils.js",
        "text/javascript",
        include_bytes!("../assets/three/utils/BufferGeometryUtils.js"),
    ),
    (
        "/three/controls/OrbitControls.js",
        "text/javascript",
        include_bytes!("../assets/three/controls/OrbitControls.js"),
    ),
];

/// The folder holding `material.gltf` for a run folder or a glTF folder.
pub fn gltf_dir(dir: &Path) -> Result<PathBuf> {
    // A run folder, or the export/gltf folder of one: refuse it while unfinished.
    let resolved = svbrdf_core::fsutil::resolve(dir);
    for run in resolved.ancestors().take(3) {
        crate::run_cmd::refuse_unfinished_run(run)?;
    }
    for d in [dir.join("export").join("gltf"), dir.to_path_buf()] {
        if d.join(svbrdf_export::gltf::GLTF_FILE).is_file() {
            return Ok(d);
        }
    }
    anyhow::bail!(
        "invalid folder {} (expected a run folder with export/gltf/material.gltf, or a folder holding material.gltf; run `svbrdf run` or `svbrdf export` first)",
        dir.display()
    )
}

/// Bind 127.0.0.1 on `port`, or on a free port when it is busy or not given.
pub fn bind(port: Option<u16>) -> Result<TcpListener> {
    if let Some(p) = port {
        match TcpListener::bind(("127.0.0.1", p)) {
            Ok(l) => return Ok(l),
            Err(e) => eprintln!("port {p} is not available ({e}); using a free port instead"),
        }
    }
    TcpListener::bind(("127.0.0.1", 0)).context("binding a free port on 127.0.0.1")
}

fn content_type(name: &str) -> &'static str {
    match name.rsplit('.').next() {
        Some("gltf") => "model/gltf+json",
        Some("bin") => "application/octet-stream",
        Some("png") => "image/png",
        Some("jpg" | "jpeg") => "image/jpeg",
        _ => "application/octet-stream",
    }
}

fn respond(stream: &mut TcpStream, status: &str, kind: &str, body: &[u8]) -> std::io::Result<()> {
    let mut out = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    )
    .into_bytes();
    out.extend_from_slice(body);
    stream.write_all(&out)?;
    stream.flush()?;
    // Close our side first and let the client read to the end: closing a socket with
    // unread input makes the kernel send a reset that can discard the response.
    stream.shutdown(std::net::Shutdown::Write)
}

/// The longest request line and header block read, bytes; longer requests get 431.
const MAX_REQUEST_BYTES: u64 = 16 * 1024;
/// The most time one request may take to arrive.
const REQUEST_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(10);

/// A file inside `dir` that may be served: a plain name, and after resolving links a
/// regular file that is still inside `dir`.
fn servable(dir: &Path, name: &str) -> Option<PathBuf> {
    let plain = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
        && !name.starts_with('.');
    if !plain {
        return None;
    }
    let root = std::fs::canonicalize(dir).ok()?;
    let file = std::fs::canonicalize(dir.join(name)).ok()?;
    (file.starts_with(&root) && std::fs::metadata(&file).ok()?.is_file()).then_some(file)
}

fn handle(mut stream: TcpStream, gltf: &Path) -> std::io::Result<()> {
    stream.set_read_timeout(Some(REQUEST_TIMEOUT))?;
    let started = std::time::Instant::now();
    // Read at most MAX_REQUEST_BYTES of request line and headers, in bounded time.
    let mut reader = BufReader::new(std::io::Read::take(stream.try_clone()?, MAX_REQUEST_BYTES));
    let mut line = String::new();
    reader.read_line(&mut line)?;
    let mut complete = line.ends_with('\n');
    let mut h = String::new();
    while complete {
        h.clear();
        if reader.read_line(&mut h)? == 0 || !h.ends_with('\n') {
            complete = false;
        } else if h.len() <= 2 {
            break;
        }
        if started.elapsed() > REQUEST_TIMEOUT {
            complete = false;
        }
    }
    if !complete {
        return respond(
            &mut stream,
            "431 Request Header Fields Too Large",
            "text/plain",
            b"request too large or incomplete\n",
        );
    }
    let mut parts = line.split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or("/"));
    if method != "GET" {
        return respond(
            &mut stream,
            "405 Method Not Allowed",
            "text/plain",
            b"GET only\n",
        );
    }
    let path = target.split(['?', '#']).next().unwrap_or("/");
    if let Some((_, kind, bytes)) = ASSETS.iter().find(|(p, ..)| *p == path) {
        return respond(&mut stream, "200 OK", kind, bytes);
    }
    if let Some(name) = path.strip_prefix("/gltf/") {
        // Only plain file names directly inside the export folder, links resolved.
        if let Some(file) = servable(gltf, name) {
            if let Ok(bytes) = std::fs::read(file) {
                return respond(&mut stream, "200 OK", content_type(name), &bytes);
            }
        }
    }
    respond(&mut stream, "404 Not Found", "text/plain", b"not found\n")
}

pub fn run_view(a: &ViewArgs) -> Result<()> {
    let gltf = gltf_dir(&a.dir)?;
    let listener = bind(a.port)?;
    let addr = listener.local_addr()?;
    // One write, errors ignored: the server keeps serving if nobody reads its stdout
    // any more (a closed pipe must not end it).
    let mut stdout = std::io::stdout().lock();
    let _ = write!(
        stdout,
        "serving {} at http://{addr}/\nopen that URL in a browser; Ctrl-C stops the server\n",
        gltf.display()
    );
    let _ = stdout.flush();
    drop(stdout);
    for stream in listener.incoming() {
        match stream {
            Ok(s) => {
                let dir = gltf.clone();
                std::thread::spawn(move || {
                    let _ = handle(s, &dir);
                });
            }
            Err(e) => eprintln!("connection failed: {e}"),
        }
    }
    Ok(())
}
