//! The JSON body of a Match, as `POST /v1/match` reads it: the fast path
//! (`match_request_from_json`) and pbjson (`from_json`) must agree, and whatever parses goes
//! through the request's conversion and checks.

use prost::Message;
use trinocular::api::{self, pb};

pub fn run(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let fast = api::match_request_from_json(text);
    let reference = api::from_json::<pb::MatchRequest>("request", text);
    match (&fast, &reference) {
        // NaN != NaN: compare the encodings.
        (Ok(a), Ok(b)) => assert_eq!(
            a.encode_to_vec(),
            b.encode_to_vec(),
            "the fast path and pbjson read different requests"
        ),
        (Err(a), Err(b)) => assert_eq!(a, b, "the fast path and pbjson fail differently"),
        _ => panic!("the fast path says {fast:?}, pbjson says {reference:?}"),
    }
    if let Ok(request) = reference {
        let checked = api::match_request(&request, &crate::request_limits());
        crate::debug(|| format!("match_request: {:?}", checked.map(|_| ())));
    } else {
        crate::debug(|| format!("from_json: {reference:?}"));
    }
}
