#!/usr/bin/env bash
# Screenshots of the documentation site in a headless browser, to check by eye that it
# renders: the pictures of the gallery load and the API pages show their generated
# entries. Not part of CI (it needs Chromium); run it by hand:
#
#     bash docs/screenshots.sh /tmp/shots
#
# It builds the site (strict) into a temporary folder, serves it on a free localhost
# port, writes home.png, gallery.png and api_render.png into the folder given as its
# first argument, lists any file the pages asked for that the server did not have (a
# broken picture: exit status 1), and stops the server. The browser is `chromium`
# (Debian: `apt-get install chromium`), or the one named by $CHROMIUM.
set -euo pipefail

if [ $# -ne 1 ]; then
    echo "usage: $0 OUTPUT_FOLDER" >&2
    exit 2
fi
mkdir -p "$1"
shots="$(cd "$1" && pwd)"
cd "$(dirname "$0")/.."

python=python3
[ -x .venv/bin/python ] && python=.venv/bin/python
browser="${CHROMIUM:-}"
if [ -z "$browser" ]; then
    for candidate in chromium chromium-browser google-chrome; do
        if command -v "$candidate" >/dev/null; then
            browser="$candidate"
            break
        fi
    done
fi
if [ -z "$browser" ]; then
    echo "no Chromium found: install it (apt-get install chromium) or set CHROMIUM" >&2
    exit 1
fi

site="$(mktemp -d)"
log="$(mktemp)"
server=""
cleanup() {
    if [ -n "$server" ]; then
        kill "$server" 2>/dev/null || true
        wait "$server" 2>/dev/null || true
    fi
    rm -rf "$site" "$log"
}
trap cleanup EXIT

NO_MKDOCS_2_WARNING=1 "$python" -m mkdocs build --strict --quiet --site-dir "$site"

port="$("$python" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
"$python" -m http.server "$port" --bind 127.0.0.1 --directory "$site" >"$log" 2>&1 &
server=$!
for attempt in $(seq 50); do
    "$python" -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:$port/')" \
        2>/dev/null && break
    if [ "$attempt" -eq 50 ]; then
        echo "the server on port $port did not start" >&2
        exit 1
    fi
    sleep 0.2
done

for page in home: gallery:gallery/ api_render:api/render/; do
    name="${page%%:*}"
    "$browser" --headless --no-sandbox --disable-gpu --hide-scrollbars \
        --window-size=1280,2000 --virtual-time-budget=5000 \
        --screenshot="$shots/$name.png" "http://127.0.0.1:$port/${page#*:}" \
        >/dev/null 2>&1
    echo "$shots/$name.png"
done

# The server logs each request; the browser fetches every picture on a page, also those
# below the window.
if grep -E '" 404 ' "$log"; then
    echo "the pages above asked for files the site does not have" >&2
    exit 1
fi
