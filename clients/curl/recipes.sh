#!/usr/bin/env bash
# curl recipes for every HTTP endpoint of `trinocular serve`, each printed before it runs (copy
# them) and checked: the HTTP status, then a jq assertion on the body (or the PNG magic / the
# PLY header). Stops with a non-zero exit at the first failure.
#
#   clients/curl/recipes.sh [BASE_URL]          # default http://127.0.0.1:8080
#
# Needs bash, curl, jq, base64, od. Inputs come from `$TRINOCULAR_BIN demo --out $TMP`
# (TRINOCULAR_BIN defaults to target/release/trinocular): img1..3.png and calibration.json.
set -euo pipefail

BASE="${1:-http://127.0.0.1:8080}"
BASE="${BASE%/}"
BIN="${TRINOCULAR_BIN:-target/release/trinocular}"
for tool in curl jq base64 od; do
  command -v "$tool" >/dev/null || { echo "recipes: missing $tool" >&2; exit 2; }
done
[ -x "$BIN" ] || { echo "recipes: no trinocular binary at $BIN (set TRINOCULAR_BIN)" >&2; exit 2; }

TMP="$(mktemp -d /tmp/trinocular-recipes.XXXXXX)"
trap 'rm -rf "$TMP"' EXIT
BODY="$TMP/body"
ID=""
passed=0

fail() { echo "FAIL: $*" >&2; echo "--- body:" >&2; head -c 2000 "$BODY" >&2 || true; echo >&2; exit 1; }

# recipe NAME STATUS CHECK CURL_ARGS...
#   CHECK: json:FILTER (jq -e on the body), raw:FILTER (jq -e on the body as one string),
#          png (the 8-byte PNG signature), ply (the "ply" header line)
# FILTERs see $id (the current session id).
recipe() {
  local name="$1" want="$2" check="$3"; shift 3
  echo
  echo "### $name"
  printf '%q ' curl -sS "$@" | sed 's/ $//'
  echo
  local got
  got="$(curl -sS -o "$BODY" -w '%{http_code}' "$@")" || fail "$name: curl failed"
  [ "$got" = "$want" ] || fail "$name: HTTP $got, expected $want"
  case "$check" in
    json:*) jq -e --arg id "$ID" "${check#json:}" "$BODY" >/dev/null \
              || fail "$name: jq assertion failed: ${check#json:}" ;;
    raw:*)  jq -R -s -e --arg id "$ID" "${check#raw:}" "$BODY" >/dev/null \
              || fail "$name: jq assertion failed (raw): ${check#raw:}" ;;
    png)    [ "$(head -c 8 "$BODY" | od -An -tx1 | tr -d ' \n')" = 89504e470d0a1a0a ] \
              || fail "$name: not a PNG (magic $(head -c 8 "$BODY" | od -An -tx1))" ;;
    ply)    [ "$(head -n 1 "$BODY" | tr -d '\r')" = ply ] || fail "$name: no 'ply' header" ;;
    *)      fail "recipe $name: unknown check $check" ;;
  esac
  echo "ok: HTTP $got, ${check}"
  passed=$((passed + 1))
}

echo "== inputs: $BIN demo --out $TMP"
"$BIN" demo --out "$TMP" >/dev/null 2>"$TMP/demo.log" || { cat "$TMP/demo.log" >&2; exit 2; }
for f in img1.png img2.png img3.png calibration.json; do
  [ -s "$TMP/$f" ] || { echo "recipes: demo did not write $f" >&2; exit 2; }
done
D="$TMP"

# A MatchRequest in proto3 JSON: the calibration and the three PNGs (bytes as base64).
jq -n --slurpfile cal "$D/calibration.json" \
  --rawfile b1 <(base64 -w0 "$D/img1.png") --rawfile b2 <(base64 -w0 "$D/img2.png") \
  --rawfile b3 <(base64 -w0 "$D/img3.png") \
  '{calibration: $cal[0], images: {images: [{encoded: $b1}, {encoded: $b2}, {encoded: $b3}]}}' \
  >"$D/request.json"
# A bad one: only two images.
jq '.images.images |= .[:2]' "$D/request.json" >"$D/bad_request.json"
# A blank 64x64 grey PNG: no calibration pattern in it.
echo 'iVBORw0KGgoAAAANSUhEUgAAAEAAAABACAAAAACPAi4CAAAAKklEQVR42u3MQREAAAwCIPsnM5Yh9ttBANKjCAQCgUAgEAgEAoFAIPgeDAQKgLWRjkNPAAAAAElFTkSuQmCC' \
  | base64 -d >"$D/blank.png"
# CreateSession body: a name and the calibration.
jq -n --slurpfile cal "$D/calibration.json" '{name: "office", calibration: $cal[0]}' >"$D/session.json"
# The same with an id the client chose, and another session under that id.
jq '. + {sessionId: "curl-recipes-office"}' "$D/session.json" >"$D/session_named.json"
jq '. + {sessionId: "curl-recipes-office", name: "another room"}' "$D/session.json" >"$D/session_other.json"

echo "== recipes against $BASE"

recipe "healthz" 200 'raw:startswith("ok")' "$BASE/healthz"
recipe "readyz" 200 'raw:startswith("ready")' "$BASE/readyz"

recipe "match (JSON, images as base64)" 200 'json:(.segments3d | length) > 0 and (.triplets | length) > 0' \
  -X POST "$BASE/v1/match" -H 'content-type: application/json' --data-binary "@$D/request.json"

recipe "match (multipart: calibration, options, image1..3)" 200 \
  'json:(.segments3d | length) > 0 and (.extracted | length) == 3' \
  -X POST "$BASE/v1/match?timeout_ms=5000" \
  -F "calibration=@$D/calibration.json" -F 'options={"returnExtracted": true}' \
  -F "image1=@$D/img1.png" -F "image2=@$D/img2.png" -F "image3=@$D/img3.png"

recipe "match, bad request (two images): 400 naming the field" 400 \
  'json:.error.code == "INVALID_ARGUMENT" and (.error.field | type == "string" and length > 0)' \
  -X POST "$BASE/v1/match" -H 'content-type: application/json' --data-binary "@$D/bad_request.json"
echo "   field: $(jq -r .error.field "$BODY")"

echo
echo "(calibrate: no pattern images come from demo, so its success path is skipped; blank images"
echo " must be refused naming the first image)"
recipe "calibrate (multipart, blank images): 400 naming images.images[0]" 400 \
  'json:.error.code == "INVALID_ARGUMENT" and .error.field == "images.images[0]"' \
  -X POST "$BASE/v1/calibrate" \
  -F "image1=@$D/blank.png" -F "image2=@$D/blank.png" -F "image3=@$D/blank.png"

recipe "sessions: create (JSON)" 200 'json:(.id | length) > 0 and .name == "office"' \
  -X POST "$BASE/v1/sessions" -H 'content-type: application/json' --data-binary "@$D/session.json"
ID="$(jq -r .id "$BODY")"
echo "   ID=$ID"

recipe "sessions: add a capture (multipart: pose, image1..3)" 200 \
  'json:(.captureIndex // 0 | tonumber) == 0 and (.map.captures | tonumber) == 1 and (.match.segments3d | length) > 0' \
  -X POST "$BASE/v1/sessions/$ID/captures?timeout_ms=5000" \
  -F 'pose=[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]' \
  -F "image1=@$D/img1.png" -F "image2=@$D/img2.png" -F "image3=@$D/img3.png"

# A capture named by the client (capture_id): if its answer is lost (a timeout, a reset), the
# same upload sent again is answered with that capture, not stored twice.
recipe "sessions: add a named capture (multipart: capture_id, pose, image1..3)" 200 \
  'json:(.captureIndex | tonumber) == 1 and (.duplicate // false) == false' \
  -X POST "$BASE/v1/sessions/$ID/captures?timeout_ms=5000" \
  -F 'capture_id=robot-1/0002' -F 'pose=[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]' \
  -F "image1=@$D/img1.png" -F "image2=@$D/img2.png" -F "image3=@$D/img3.png"
recipe "sessions: the same named capture again (a retry): answered, not stored" 200 \
  'json:(.captureIndex | tonumber) == 1 and .duplicate == true and (.map.captures | tonumber) == 2' \
  -X POST "$BASE/v1/sessions/$ID/captures?timeout_ms=5000" \
  -F 'capture_id=robot-1/0002' -F 'pose=[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]' \
  -F "image1=@$D/img1.png" -F "image2=@$D/img2.png" -F "image3=@$D/img3.png"

recipe "sessions: get" 200 'json:.id == $id and (.captures | tonumber) == 2' "$BASE/v1/sessions/$ID"
recipe "sessions: list" 200 'json:[.sessions[].id] | index($id) != null' "$BASE/v1/sessions"
recipe "sessions: map (JSON)" 200 \
  'json:.sessionId == $id and (.segments | length) > 0 and (.poses | length) == 2' \
  "$BASE/v1/sessions/$ID/map?format=json"
recipe "sessions: map (PNG top view)" 200 png "$BASE/v1/sessions/$ID/map?format=png"
recipe "sessions: map (PLY)" 200 ply "$BASE/v1/sessions/$ID/map?format=ply&min_observations=1"
recipe "sessions: delete" 200 'json:. == {}' -X DELETE "$BASE/v1/sessions/$ID"
recipe "sessions: get after delete: 404 naming session_id" 404 \
  'json:.error.code == "NOT_FOUND" and .error.field == "session_id"' "$BASE/v1/sessions/$ID"

# A session the client names (sessionId): created again as it was (a retry whose answer was
# lost), it is the same session; the same id for another session is 409 naming session_id.
recipe "sessions: create under a chosen id" 200 'json:.id == "curl-recipes-office"' \
  -X POST "$BASE/v1/sessions" -H 'content-type: application/json' --data-binary "@$D/session_named.json"
recipe "sessions: the same create again (a retry): the same session" 200 \
  'json:.id == "curl-recipes-office" and .name == "office"' \
  -X POST "$BASE/v1/sessions" -H 'content-type: application/json' --data-binary "@$D/session_named.json"
recipe "sessions: that id for another session: 409 naming session_id" 409 \
  'json:.error.code == "ALREADY_EXISTS" and .error.field == "session_id"' \
  -X POST "$BASE/v1/sessions" -H 'content-type: application/json' --data-binary "@$D/session_other.json"
recipe "sessions: delete the named one" 200 'json:. == {}' -X DELETE "$BASE/v1/sessions/curl-recipes-office"

recipe "metrics (Prometheus text)" 200 'raw:contains("trinocular_requests_total")' "$BASE/metrics"

echo
echo "all $passed recipes passed against $BASE"
