"""What a browser meets besides the API: the favicon, and an access log that does not fill with
the studio's progress polls."""
import time


def test_the_favicon_is_served(client):
    r = client.get("/favicon.ico")
    assert r.status_code == 200 and r.headers["content-type"] == "image/svg+xml", (r.status_code, r.headers)
    assert r.content.lstrip().startswith(b"<svg")
    page = client.get("/").text
    assert 'rel="icon" href="/web/favicon.svg"' in page
    assert client.get("/web/favicon.svg").status_code == 200


def test_progress_polls_are_not_access_lines_but_failures_are(client, server):
    """Ten polls of /v1/status (the studio polls every 0.7 s while the demo precomputes) leave no
    INFO access line; a poll that fails (404) and any other request still do."""
    marker = f"marker-{time.monotonic_ns()}"
    for _ in range(10):
        assert client.get("/v1/status", headers={"X-Request-ID": f"{marker}-poll"}).status_code == 200
    assert client.get("/v1/scenes/no-such-scene", headers={"X-Request-ID": f"{marker}-miss"}).status_code == 404
    assert client.get("/v1/models", headers={"X-Request-ID": f"{marker}-models"}).status_code == 200
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        log = server["server"].log()
        if f"[{marker}-models]" in log:
            break
        time.sleep(0.1)
    lines = [x for x in log.splitlines() if marker in x]
    polls = [x for x in lines if f"[{marker}-poll]" in x]
    assert not polls, f"{len(polls)} access lines for progress polls, e.g. {polls[:1]}"
    assert any(f"[{marker}-miss]" in x and " 404 " in x for x in lines), lines
    assert any(f"[{marker}-models]" in x and "/v1/models" in x for x in lines), lines
