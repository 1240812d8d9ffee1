//! A `multipart/form-data` body (boundary `X`) posted to the real router: to `/v1/match` and to
//! a session's `/v1/sessions/{id}/captures`. Whatever the body, the answer must be a client
//! error or a success, never a 5xx.

use crate::Http;
use axum::body::Body;
use axum::http::{Request, StatusCode};

const CONTENT_TYPE: &str = "multipart/form-data; boundary=X";

fn post(http: &Http, uri: &str, data: &[u8]) -> StatusCode {
    let request = Request::post(uri)
        .header("content-type", CONTENT_TYPE)
        .body(Body::from(data.to_vec()))
        .unwrap();
    http.send_checked(request).status
}

pub fn run(data: &[u8]) {
    let http = Http::get();
    post(http, "/v1/match", data);
    let captures = format!("/v1/sessions/{}/captures", http.session());
    if post(http, &captures, data) == StatusCode::OK {
        http.new_session();
    }
}
