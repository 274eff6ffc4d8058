//! What the HTML pages matup writes (the batch index, the viewer) share.

use percent_encoding::{utf8_percent_encode, AsciiSet, NON_ALPHANUMERIC};

/// `text` for HTML content or a quoted attribute.
pub fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&#39;")
}

/// What a URL path segment may hold unencoded (RFC 3986's unreserved characters).
const SEGMENT: &AsciiSet = &NON_ALPHANUMERIC
    .remove(b'-')
    .remove(b'.')
    .remove(b'_')
    .remove(b'~');

/// A relative URL to `file` in the folder `folder` ('/'-separated, "." for this one; to the
/// folder itself when `file` is empty), each path segment percent-encoded.
pub fn href(folder: &str, file: &str) -> String {
    let mut url = String::from(".");
    for segment in folder.split('/').filter(|s| *s != ".") {
        url.push('/');
        url.extend(utf8_percent_encode(segment, SEGMENT));
    }
    url.push('/');
    url.extend(utf8_percent_encode(file, SEGMENT));
    url
}
