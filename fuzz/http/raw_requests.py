#!/usr/bin/env python3
"""Malformed raw HTTP/1.1 requests against a running
`ilqr-service serve --bind 127.0.0.1:PORT --read-timeout-secs 2`: a fixed
list (not coverage-guided) of framing, header, method and path oddities.
Every answer must come within 10 s and never be a 5xx, and the server must
stay alive (GET /healthz after each case). Prints one line per case.
Usage: python3 fuzz/http/raw_requests.py PORT (exit 1 on any finding)"""
import gzip, re, socket, sys, time

PORT = int(sys.argv[1])
SEED = b'{}'
findings = []

def send(raw, read_timeout=15.0):
    """Sends `raw`, then reads until the server closes (or `read_timeout`)."""
    s = socket.create_connection(("127.0.0.1", PORT), timeout=read_timeout)
    t0 = time.monotonic()
    try:
        try:
            s.sendall(raw)
        except OSError:
            # The server may answer (413, 400) and close before it has read
            # everything: read what it said all the same.
            pass
        data = b""
        while True:
            try:
                chunk = s.recv(65536)
            except socket.timeout:
                return data, time.monotonic() - t0, "TIMEOUT"
            except ConnectionResetError:
                return data, time.monotonic() - t0, "RESET"
            if not chunk: break
            data += chunk
        return data, time.monotonic() - t0, "EOF"
    finally:
        s.close()

def statuses(data):
    # Status lines anywhere: a pipelined answer starts right after the
    # previous body, which need not end in CRLF.
    return [int(m) for m in re.findall(rb"HTTP/1\.[01] (\d{3}) ", data)]

def alive():
    try:
        d, _, _ = send(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n", 5)
        return statuses(d)[:1] == [200]
    except OSError:
        return False

def req(method=b"POST", path=b"/solve", headers=(), body=b"", version=b"HTTP/1.1"):
    h = b"".join(k + b": " + v + b"\r\n" for k, v in headers)
    return method + b" " + path + b" " + version + b"\r\n" + h + b"\r\n" + body

J = (b"Content-Type", b"application/json")
H = (b"Host", b"x")
C = (b"Connection", b"close")
def cl(b): return (b"Content-Length", str(len(b)).encode())

def chunked(body, size_fmt="{:x}", ext=b"", trailer=b""):
    return size_fmt.format(len(body)).encode() + ext + b"\r\n" + body + b"\r\n0\r\n" + trailer + b"\r\n"

small = b'{"horizon": 20, "solver": {"time_limit_ms": 50}}'
cases = {
 "chunked_ok": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked")], body=chunked(small)),
 "chunked_ext": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked")], body=chunked(small, ext=b";foo=bar")),
 "chunked_trailer": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked")], body=chunked(small, trailer=b"X-T: 1\r\n")),
 "chunked_bad_hex": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked")], body=b"zz\r\n{}\r\n0\r\n\r\n"),
 "chunked_huge_size": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked")], body=b"ffffffffffffffff\r\n{}\r\n0\r\n\r\n"),
 "chunked_overflow_size": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked")], body=b"1ffffffffffffffff\r\n{}\r\n0\r\n\r\n"),
 "chunked_truncated": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked")], body=b"10\r\n{}"),
 "chunked_over_limit": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked")], body=b"".join([b"100000\r\n" + b" " * 0x100000 + b"\r\n"] * 5) + b"0\r\n\r\n"),
 "te_and_cl": req(headers=[H, J, C, (b"Transfer-Encoding", b"chunked"), (b"Content-Length", b"3")], body=chunked(small)),
 "te_gzip_chunked": req(headers=[H, J, C, (b"Transfer-Encoding", b"gzip, chunked")], body=chunked(gzip.compress(small))),
 "te_identity": req(headers=[H, J, C, (b"Transfer-Encoding", b"identity"), cl(small)], body=small),
 "two_cl_differ": req(headers=[H, J, C, (b"Content-Length", b"2"), (b"Content-Length", b"3")], body=b"{} "),
 "two_cl_same": req(headers=[H, J, C, (b"Content-Length", b"2"), (b"Content-Length", b"2")], body=b"{}"),
 "cl_list": req(headers=[H, J, C, (b"Content-Length", b"2, 2")], body=b"{}"),
 "cl_neg": req(headers=[H, J, C, (b"Content-Length", b"-1")], body=b"{}"),
 "cl_plus": req(headers=[H, J, C, (b"Content-Length", b"+2")], body=b"{}"),
 "cl_huge": req(headers=[H, J, C, (b"Content-Length", b"99999999999999999999999")], body=b"{}"),
 "cl_u64max": req(headers=[H, J, C, (b"Content-Length", b"18446744073709551615")], body=b"{}"),
 "cl_over_limit": req(headers=[H, J, C, (b"Content-Length", b"4194305")], body=b"{}"),
 "cl_short_body": req(headers=[H, J, C, (b"Content-Length", b"100")], body=b"{}"),
 "cl_zero": req(headers=[H, J, C, (b"Content-Length", b"0")]),
 "no_cl_post": req(headers=[H, J, C]),
 "expect_100": req(headers=[H, J, C, (b"Expect", b"100-continue"), cl(small)], body=small),
 "expect_100_over": req(headers=[H, J, C, (b"Expect", b"100-continue"), (b"Content-Length", b"5000000")]),
 "expect_weird": req(headers=[H, J, C, (b"Expect", b"x-weird"), cl(small)], body=small),
 "ce_gzip": req(headers=[H, J, C, (b"Content-Encoding", b"gzip"), cl(gzip.compress(small))], body=gzip.compress(small)),
 "ce_identity_upper": req(headers=[H, J, C, (b"Content-Encoding", b"IDENTITY"), cl(small)], body=small),
 "ce_list": req(headers=[H, J, C, (b"Content-Encoding", b"identity, identity"), cl(small)], body=small),
 "ce_empty": req(headers=[H, J, C, (b"Content-Encoding", b""), cl(small)], body=small),
 "ct_utf16": req(headers=[H, C, (b"Content-Type", b"application/json; charset=utf-16"), cl(small)], body=small),
 "ct_plusjson": req(headers=[H, C, (b"Content-Type", b"application/vnd.x+json"), cl(small)], body=small),
 "ct_upper": req(headers=[H, C, (b"Content-Type", b"APPLICATION/JSON ; CHARSET=\"UTF-8\""), cl(small)], body=small),
 "ct_obs_text": req(headers=[H, C, (b"Content-Type", b"application/json; x=\xff\xfe"), cl(small)], body=small),
 "ct_two": req(headers=[H, C, J, (b"Content-Type", b"text/plain"), cl(small)], body=small),
 "ct_empty": req(headers=[H, C, (b"Content-Type", b""), cl(small)], body=small),
 "ct_semicolons": req(headers=[H, C, (b"Content-Type", b"application/json;;;;charset"), cl(small)], body=small),
 "huge_header": req(headers=[H, J, C, (b"X-Big", b"a" * 600_000), cl(small)], body=small),
 "many_headers": req(headers=[H, J, C] + [(b"X-%d" % i, b"1") for i in range(150)] + [cl(small)], body=small),
 "obs_fold": b"POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n  folded\r\nConnection: close\r\nContent-Length: 2\r\n\r\n{}",
 "nul_in_header": req(headers=[H, J, C, (b"X-N", b"a\x00b"), cl(small)], body=small),
 "http10": req(headers=[J, cl(small)], body=small, version=b"HTTP/1.0"),
 "http09": b"GET /healthz\r\n\r\n",
 "http2_preface": b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n",
 "h2c_upgrade": req(headers=[H, J, C, (b"Upgrade", b"h2c"), (b"HTTP2-Settings", b"AAMAAABkAARAAAAAAAIAAAAA"), cl(small)], body=small),
 "ws_upgrade": req(method=b"GET", path=b"/healthz", headers=[H, C, (b"Upgrade", b"websocket"), (b"Connection", b"Upgrade")]),
 "options_star": req(method=b"OPTIONS", path=b"*", headers=[H, C]),
 "connect": req(method=b"CONNECT", path=b"127.0.0.1:1", headers=[H, C]),
 "absolute_uri": req(path=b"http://evil/solve", headers=[H, J, C, cl(small)], body=small),
 "lower_method": req(method=b"post", headers=[H, J, C, cl(small)], body=small),
 "weird_method": req(method=b"FOO", headers=[H, J, C, cl(small)], body=small),
 "head_solve": req(method=b"HEAD", headers=[H, J, C]),
 "get_solve_body": req(method=b"GET", headers=[H, J, C, cl(small)], body=small),
 "path_trailing": req(path=b"/solve/", headers=[H, J, C, cl(small)], body=small),
 "path_query": req(path=b"/solve?x=%ff&&==", headers=[H, J, C, cl(small)], body=small),
 "path_double": req(path=b"//solve", headers=[H, J, C, cl(small)], body=small),
 "path_dotdot": req(path=b"/%2e%2e/solve", headers=[H, J, C, cl(small)], body=small),
 "path_pct_bad": req(path=b"/so%zzlve", headers=[H, J, C, cl(small)], body=small),
 "path_utf8": req(path="/sölve".encode(), headers=[H, J, C, cl(small)], body=small),
 "path_long": req(method=b"GET", path=b"/" + b"a" * 100_000, headers=[H, C]),
 "docs_traversal": req(method=b"GET", path=b"/docs/../../etc/passwd", headers=[H, C]),
 "docs_long": req(method=b"GET", path=b"/docs/" + b"x" * 5000, headers=[H, C]),
 "ae_weird": req(headers=[H, J, C, (b"Accept-Encoding", b"gzip;q=0.5000, *;q=nan, ,,;;,br;q=1"), cl(small)], body=small),
 "ae_zero": req(headers=[H, J, C, (b"Accept-Encoding", b"*;q=0"), cl(small)], body=small),
 "ae_long": req(headers=[H, J, C, (b"Accept-Encoding", b"gzip;" * 20000), cl(small)], body=small),
 "ae_obs": req(headers=[H, J, C, (b"Accept-Encoding", b"gzip\xff"), cl(small)], body=small),
 "reqid_weird": req(headers=[H, J, C, (b"X-Request-Id", b"\x80\x81"), (b"X-Request-Id", b"two"), cl(small)], body=small),
 "reqid_long": req(headers=[H, J, C, (b"X-Request-Id", b"a" * 70000), cl(small)], body=small),
 "pipelined": req(headers=[H, J, cl(small)], body=small) * 3 + req(method=b"GET", path=b"/healthz", headers=[H, C]),
 "pipelined_garbage": req(headers=[H, J, cl(small)], body=small) + b"GARBAGE\r\n\r\n",
 "bare_lf": b"POST /solve HTTP/1.1\nHost: x\nContent-Type: application/json\nConnection: close\nContent-Length: 2\n\n{}",
 "space_before_colon": b"POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type : application/json\r\nConnection: close\r\nContent-Length: 2\r\n\r\n{}",
 "binary_junk": bytes(range(256)) * 4,
 "empty_then_close": b"",
 "metrics_post": req(path=b"/metrics", headers=[H, J, C, cl(small)], body=small),
 "problems_default_head": req(method=b"HEAD", path=b"/problems/default", headers=[H, C]),
 "gzip_answer": req(headers=[H, J, C, (b"Accept-Encoding", b"gzip"), cl(small)], body=small),
 # Stalls: the server's read timeout (2 s here) must end them, a half-sent
 # body with 408 and an unfinished head by closing the connection.
 "stall_body": req(headers=[H, J, C, (b"Content-Length", b"100")], body=b'{"dt"'),
 "stall_head": b"POST /solve HTTP/1.1\r\nHost: x\r\n",
 "horizon_10000": req(headers=[H, J, C, (b"Accept-Encoding", b"gzip")] + [cl(b'{"horizon": 10000, "dt": 0.001, "solver": {"time_limit_ms": 20}}')], body=b'{"horizon": 10000, "dt": 0.001, "solver": {"time_limit_ms": 20}}'),
}

for name, raw in cases.items():
    try:
        data, took, how = send(raw)
    except OSError as e:
        data, took, how = b"", 0.0, "ERR " + str(e)
    st = statuses(data)
    ok = alive()
    head = data.split(b"\r\n", 1)[0][:80]
    flag = ""
    if any(s >= 500 for s in st) or not ok or how == "TIMEOUT" or took > 10:
        flag = "  <-- FINDING?"
        findings.append(name)
    print(f"{name:22s} {str(st):22s} {how:8s} {took*1000:8.1f} ms alive={ok} {head!r}{flag}")

print("FINDINGS:", findings)
sys.exit(1 if findings else 0)
