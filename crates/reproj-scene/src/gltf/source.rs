//! The bytes of a glTF model: the file itself (regular files only, size-capped), the GLB
//! container split by hand with every chunk length checked against the bytes present, the JSON
//! document, and its buffers and image files (data URIs decoded here, external files read with
//! the same cap). Nothing read from the file sizes an allocation before it is checked.
//! Each external file is read once and hashed (SHA-256) from the bytes read, for
//! [`crate::gltf::ModelFiles`].

use std::collections::HashMap;
use std::io::Read;
use std::path::{Component, Path, PathBuf};
use std::sync::Arc;

use sha2::{Digest, Sha256};

use super::{err, unsupported};
use crate::error::Result;

/// Largest file read (the glTF or GLB file, an external buffer or texture): 1 GiB, far above
/// any model the CPU renderer can draw.
pub(crate) const MAX_FILE_BYTES: u64 = 1 << 30;

/// Largest sum of bytes read for one model (file, buffers and textures).
pub(crate) const MAX_INPUT_BYTES: u64 = 2 << 30;

/// The first four bytes of a GLB file.
pub(super) const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// Reads the regular file at `path` (a FIFO or a device would block or never end), refusing one
/// over `cap` bytes. `what` names it in messages.
pub(super) fn read_file(model: &Path, path: &Path, what: &str, cap: u64) -> Result<Vec<u8>> {
    let meta = std::fs::metadata(path)
        .map_err(|e| err(model, format!("cannot read {what} {}: {e}", path.display())))?;
    if !meta.is_file() {
        return Err(err(
            model,
            format!("{what} {} is not a regular file", path.display()),
        ));
    }
    let file = std::fs::File::open(path)
        .map_err(|e| err(model, format!("cannot read {what} {}: {e}", path.display())))?;
    // The size is read, not trusted: at most cap + 1 bytes are taken, whatever st_size says.
    let mut data = Vec::new();
    file.take(cap + 1)
        .read_to_end(&mut data)
        .map_err(|e| err(model, format!("cannot read {what} {}: {e}", path.display())))?;
    if data.len() as u64 > cap {
        return Err(err(
            model,
            format!(
                "{what} {} is larger than the limit of {cap} bytes",
                path.display()
            ),
        ));
    }
    Ok(data)
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// Splits a GLB file into its JSON chunk and optional BIN chunk. The header's total length and
/// each chunk's length are checked against the bytes present before any is used.
///
/// # Errors
/// [`crate::SceneError::Gltf`] naming the field, its value and what the file holds.
pub(super) fn split_glb<'a>(path: &Path, data: &'a [u8]) -> Result<(&'a [u8], Option<&'a [u8]>)> {
    if data.len() < 20 {
        return Err(err(
            path,
            format!(
                "GLB file of {} bytes, expected at least 20 (header and a chunk header)",
                data.len()
            ),
        ));
    }
    let version = u32_at(data, 4);
    if version != 2 {
        return Err(err(path, format!("GLB version {version}, expected 2")));
    }
    let length = u32_at(data, 8) as usize;
    if length > data.len() || length < 20 {
        return Err(err(
            path,
            format!(
                "GLB header length {length}, expected 20..={} (the file's size)",
                data.len()
            ),
        ));
    }
    let data = &data[..length];
    let mut at = 12;
    let mut chunks = Vec::new();
    while at + 8 <= data.len() && chunks.len() < 2 {
        let (len, ty) = (u32_at(data, at) as usize, u32_at(data, at + 4));
        let start = at + 8;
        if len > data.len() - start {
            return Err(err(
                path,
                format!(
                    "GLB chunk {} at byte {at} declares {len} bytes, only {} follow",
                    chunks.len(),
                    data.len() - start
                ),
            ));
        }
        chunks.push((ty, &data[start..start + len]));
        // Chunks are 4-byte aligned; a length that is not is tolerated (the next header is
        // then read where the padding would end).
        at = start + len.div_ceil(4) * 4;
    }
    match chunks.as_slice() {
        [(CHUNK_JSON, json), rest @ ..] => {
            let bin = match rest.first() {
                Some(&(CHUNK_BIN, b)) => Some(b),
                _ => None,
            };
            Ok((json, bin))
        }
        _ => Err(err(path, "GLB file's first chunk is not JSON")),
    }
}

/// Parses and validates the JSON document.
pub(super) fn parse_document(path: &Path, json: &[u8]) -> Result<gltf::Document> {
    let text = json.trim_ascii_start();
    // `gltf` would take bytes starting with "glTF" for a GLB container again; only an object
    // is a glTF document.
    if !text.starts_with(b"{") {
        return Err(err(path, "malformed glTF: expected a JSON object"));
    }
    let root: gltf::json::Root = gltf::json::deserialize::from_slice(text)
        .map_err(|e| err(path, format!("malformed glTF: {e}")))?;
    // The validation below indexes the accessors with each POSITION index unchecked.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (k, p) in mesh.primitives.iter().enumerate() {
            let semantic = gltf::json::validation::Checked::Valid(gltf::Semantic::Positions);
            if let Some(a) = p.attributes.get(&semantic) {
                if a.value() >= root.accessors.len() {
                    return Err(err(
                        path,
                        format!(
                            "mesh {m} primitive {k}: POSITION is accessor {}, which does not \
                             exist ({} accessors)",
                            a.value(),
                            root.accessors.len()
                        ),
                    ));
                }
            }
        }
    }
    // Before the validation, which refuses an extension the crate does not know as "malformed
    // glTF: invalid glTF: extensionsRequired[0] = ...: Unsupported extension": the file may be
    // well-formed; the renderer implements no extension a file can require.
    if let Some(ext) = root.extensions_required.first() {
        return Err(unsupported(
            path,
            format!("required extension {ext} (the renderer implements none)"),
        ));
    }
    gltf::Document::from_json(root).map_err(|e| err(path, format!("malformed glTF: {e}")))
}

/// Where a URI's bytes come from.
enum Uri {
    /// The base64 payload of a `data:` URI.
    Data(String),
    /// A file relative to the model's folder.
    File(PathBuf),
}

fn parse_uri(path: &Path, base: &Path, uri: &str) -> Result<Uri> {
    if let Some(rest) = uri.strip_prefix("data:") {
        return match rest.split_once(";base64,") {
            Some((_, payload)) => Ok(Uri::Data(payload.to_string())),
            None => Err(err(
                path,
                format!(
                    "data URI {:?}… is not base64, expected data:<type>;base64,<data>",
                    uri.chars().take(40).collect::<String>()
                ),
            )),
        };
    }
    if uri.contains(':') {
        return Err(err(
            path,
            format!("URI {uri:?}: expected a relative path or a data: URI"),
        ));
    }
    let name = percent_decode(path, uri)?;
    if is_absolute(&name) {
        // `base.join` of an absolute path discards the base: "/etc/passwd" (or
        // "%2Fetc%2Fpasswd") would read any file on the machine. glTF 2.0 resolves a URI
        // against the model's folder; ".." stays allowed, as real assets share textures so.
        let decoded = if name == uri {
            String::new()
        } else {
            format!(" (decoded {name:?})")
        };
        return Err(err(
            path,
            format!(
                "URI {uri:?}{decoded} is an absolute path, expected a relative path or a data: URI"
            ),
        ));
    }
    Ok(Uri::File(base.join(name)))
}

/// Whether `name` (a decoded URI) would not stay relative to the model's folder, on this host
/// (`Path::has_root`, a Windows prefix) or on Windows: a leading '/' or '\' (root, UNC) or a
/// drive letter ("C:", written "C%3A" to pass the ':' check above). A model is refused alike
/// on every host rather than read here and refused there.
fn is_absolute(name: &str) -> bool {
    let p = Path::new(name);
    let drive = matches!(name.as_bytes(), [l, b':', ..] if l.is_ascii_alphabetic());
    // A prefix ("C:", "\\server\share") can only be the first component.
    let prefix = matches!(p.components().next(), Some(Component::Prefix(_)));
    name.starts_with(['/', '\\']) || drive || p.has_root() || prefix
}

/// `%XX` escapes of a relative URI, decoded; the result must be UTF-8.
fn percent_decode(path: &Path, uri: &str) -> Result<String> {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| {
                    err(
                        path,
                        format!("URI {uri:?}: '%' at byte {i} is not followed by two hex digits"),
                    )
                })?;
            out.push(hex);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| {
        err(
            path,
            format!("URI {uri:?} decodes to a name that is not UTF-8"),
        )
    })
}

/// Decodes standard base64 (padding optional, no whitespace). The output is at most 3/4 of the
/// input, so it never exceeds what the file holds.
pub(super) fn base64_decode(text: &str) -> Option<Vec<u8>> {
    let t = text.trim_end_matches('=').as_bytes();
    if t.len() % 4 == 1 {
        return None;
    }
    let value = |c: u8| match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    };
    let mut out = Vec::with_capacity(t.len() / 4 * 3 + 2);
    for quad in t.chunks(4) {
        let mut n = 0u32;
        for (k, &c) in quad.iter().enumerate() {
            n |= u32::from(value(c)?) << (18 - 6 * k);
        }
        let bytes = n.to_be_bytes();
        out.extend_from_slice(&bytes[1..quad.len()]);
    }
    Some(out)
}

/// The SHA-256 of `bytes` as 64 lower-case hex digits.
pub(super) fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Reads URIs (buffers, textures) once each, keeping the sum of bytes read under
/// [`MAX_INPUT_BYTES`], and hashes each file read.
pub(super) struct Sources<'p> {
    path: &'p Path,
    base: PathBuf,
    files: HashMap<PathBuf, Arc<Vec<u8>>>,
    /// SHA-256 (hex) of each file read, from the bytes read.
    hashes: HashMap<PathBuf, String>,
    /// Bytes of input so far (the model file and every distinct file or data URI read).
    pub(super) input: u64,
}

impl<'p> Sources<'p> {
    pub(super) fn new(path: &'p Path, file_bytes: usize) -> Sources<'p> {
        Sources {
            path,
            base: path.parent().unwrap_or(Path::new(".")).to_path_buf(),
            files: HashMap::new(),
            hashes: HashMap::new(),
            input: file_bytes as u64,
        }
    }

    /// The bytes behind `uri`; `what` names the referrer ("buffer 1", "texture of image 0").
    pub(super) fn read(&mut self, uri: &str, what: &str) -> Result<Arc<Vec<u8>>> {
        match parse_uri(self.path, &self.base, uri)? {
            Uri::Data(payload) => base64_decode(&payload)
                .map(Arc::new)
                .ok_or_else(|| err(self.path, format!("{what}: data URI is not valid base64"))),
            Uri::File(file) => {
                if let Some(d) = self.files.get(&file) {
                    return Ok(d.clone());
                }
                let d = Arc::new(self.read_new(&file, what)?);
                self.files.insert(file, d.clone());
                Ok(d)
            }
        }
    }

    /// The SHA-256 (hex) of the file behind `uri`, `None` for a `data:` URI. A file already
    /// read ([`Sources::read`]) is not read again: its digest is of the bytes decoded. Any
    /// other (an image no material uses as its base colour) is read now, once, under the same
    /// caps, hashed and dropped. Called after decoding, so it changes nothing decoded.
    pub(super) fn sha256(&mut self, uri: &str, what: &str) -> Result<Option<String>> {
        // Before parse_uri, which would copy the payload.
        if uri.starts_with("data:") {
            return Ok(None);
        }
        match parse_uri(self.path, &self.base, uri)? {
            Uri::Data(_) => Ok(None),
            Uri::File(file) => {
                if let Some(h) = self.hashes.get(&file) {
                    return Ok(Some(h.clone()));
                }
                self.read_new(&file, what)?;
                Ok(self.hashes.get(&file).cloned())
            }
        }
    }

    /// Reads `file` (not read before), charging it to the input and recording its digest.
    fn read_new(&mut self, file: &Path, what: &str) -> Result<Vec<u8>> {
        let left = MAX_INPUT_BYTES.saturating_sub(self.input);
        let cap = MAX_FILE_BYTES.min(left);
        let d = read_file(self.path, file, what, cap)?;
        self.input += d.len() as u64;
        self.hashes.insert(file.to_path_buf(), sha256_hex(&d));
        Ok(d)
    }
}
