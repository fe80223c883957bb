#!/usr/bin/env python3
"""The workspace's layout in numbers, for issue 35's targets: lines of code per crate (src only, comments, blank
lines and #[cfg(test)] code left out), functions longer than N lines, and module import cycles per crate.

    python3 tools/layout.py loc
    python3 tools/layout.py long-fns 120
    python3 tools/layout.py cycles

A rough scanner, not a Rust parser: comments and string literals are blanked, braces counted. A module's edges are
its `crate::`, `super::`, `self::` and child-module paths outside #[cfg(test)]; a child naming its own ancestor is
not an edge (a folder module and its files are one place)."""
import os, re, sys, json
from collections import defaultdict

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
def _members():
    text = open(os.path.join(ROOT, 'Cargo.toml')).read()
    return re.findall(r'"([^"]+)"', re.search(r'members\s*=\s*\[([^\]]*)\]', text).group(1))


CRATES = _members()

def strip(src):
    """Replace comments and string/char literal contents with spaces, keeping newlines and length."""
    out = list(src); i = 0; n = len(src)
    def blank(a, b):
        for k in range(a, b):
            if out[k] != '\n': out[k] = ' '
    while i < n:
        c = src[i]
        if src.startswith('//', i):
            j = src.find('\n', i); j = n if j < 0 else j
            blank(i, j); i = j; continue
        if src.startswith('/*', i):
            depth = 1; j = i + 2
            while j < n and depth:
                if src.startswith('/*', j): depth += 1; j += 2
                elif src.startswith('*/', j): depth -= 1; j += 2
                else: j += 1
            blank(i, j); i = j; continue
        m = re.match(r'b?r(#*)"', src[i:i+40])
        if m and (i == 0 or not (src[i-1].isalnum() or src[i-1] == '_')):
            hashes = m.group(1); end = '"' + hashes
            j = src.find(end, i + m.end()); j = n if j < 0 else j + len(end)
            blank(i + m.end(), j - len(end)); i = j; continue
        if c == '"' or (c == 'b' and src.startswith('b"', i) and (i == 0 or not (src[i-1].isalnum() or src[i-1]=='_'))):
            j = i + (2 if c == 'b' else 1)
            while j < n and src[j] != '"':
                j += 2 if src[j] == '\\' else 1
            blank(i + 1, j); i = j + 1; continue
        if c == "'":
            # char literal vs lifetime
            m = re.match(r"'(\\.[^']*|[^\\'])'", src[i:i+12])
            if m:
                blank(i + 1, i + m.end() - 1); i += m.end(); continue
        i += 1
    return ''.join(out)

def match_brace(s, k):
    """s[k] == '{'; return index of matching '}'."""
    d = 0
    for j in range(k, len(s)):
        if s[j] == '{': d += 1
        elif s[j] == '}':
            d -= 1
            if d == 0: return j
    return len(s) - 1

def line_of(s, k):
    return s.count('\n', 0, k) + 1

def test_spans(s):
    """Char spans of #[cfg(test)] items with a brace body (mod tests { } etc.) and names of #[cfg(test)] mod x; decls."""
    spans = []; decls = []
    for m in re.finditer(r'#\[cfg\(test\)\]', s):
        rest = s[m.end():]
        mm = re.match(r'(\s*#\[[^\]]*\])*\s*(pub(\([^)]*\))?\s+)?mod\s+(\w+)\s*([;{])', rest)
        if mm:
            if mm.group(5) == ';':
                decls.append(mm.group(4)); continue
            k = m.end() + mm.end() - 1
            spans.append((m.start(), match_brace(s, k)))
        else:
            # other cfg(test) items (fn, impl, use): skip to their body end or ;
            mm = re.match(r'[^{;]*([{;])', rest)
            if mm and mm.group(1) == '{':
                k = m.end() + mm.end() - 1
                spans.append((m.start(), match_brace(s, k)))
    return spans, decls

def in_spans(k, spans):
    return any(a <= k <= b for a, b in spans)

def files(crate):
    base = os.path.join(ROOT, crate, 'src')
    for dp, dn, fn in os.walk(base):
        for f in fn:
            if f.endswith('.rs'): yield os.path.join(dp, f)

def rel(p): return os.path.relpath(p, ROOT)

def test_files(crate):
    """Files that are #[cfg(test)] mod x; children."""
    res = set()
    for p in files(crate):
        s = strip(open(p).read())
        _, decls = test_spans(s)
        d = os.path.dirname(p); stem = os.path.basename(p)[:-3]
        sub = d if stem in ('lib', 'main', 'mod') else os.path.join(d, stem)
        for name in decls:
            for cand in (os.path.join(sub, name + '.rs'), os.path.join(sub, name, 'mod.rs')):
                if os.path.exists(cand): res.add(cand)
            if os.path.isdir(os.path.join(sub, name)):
                for dp, _, fns in os.walk(os.path.join(sub, name)):
                    for f in fns: res.add(os.path.join(dp, f))
    return res

FN_RE = re.compile(r'\bfn\s+([A-Za-z_]\w*)')
def functions(p):
    raw = open(p).read(); s = strip(raw)
    spans, _ = test_spans(s)
    res = []
    for m in FN_RE.finditer(s):
        if in_spans(m.start(), spans): continue
        depth = 0; j = m.end()
        while j < len(s):
            ch = s[j]
            if ch in '([': depth += 1
            elif ch in ')]': depth -= 1
            elif depth == 0 and ch in '{;': break
            j += 1
        if j >= len(s) or s[j] == ';': continue
        e = match_brace(s, j)
        a, b = line_of(s, m.start()), line_of(s, e)
        res.append((b - a + 1, rel(p), a, m.group(1)))
    return res

def loc(p, drop_tests=True):
    raw = open(p).read(); s = strip(raw)
    spans, _ = test_spans(s) if drop_tests else ([], [])
    lines = s.split('\n'); pos = 0; n = 0
    for ln in lines:
        if ln.strip() and not (drop_tests and in_spans(pos, spans)): n += 1
        pos += len(ln) + 1
    return n


def modname(crate, p):
    r = os.path.relpath(p, os.path.join(ROOT, crate, 'src'))[:-3].split('/')
    if r[-1] in ('lib', 'main', 'mod'): r = r[:-1]
    if r and r[0] == 'bin': return None
    return '::'.join(r)

def resolve(mods, cur, path):
    parts = path.split('::')
    if parts[0] == 'crate': base = []; parts = parts[1:]
    elif parts[0] == 'super':
        base = cur.split('::') if cur else []
        while parts and parts[0] == 'super': base = base[:-1]; parts = parts[1:]
    elif parts[0] == 'self': base = cur.split('::') if cur else []; parts = parts[1:]
    else: return None
    best = None
    for k in range(len(parts) + 1):
        cand = '::'.join(base + parts[:k])
        if cand in mods: best = cand
    return best


def cycles():
    for crate in CRATES:
        files = {}
        for dp, _, fns in os.walk(os.path.join(ROOT, crate, 'src')):
            for f in fns:
                if f.endswith('.rs'):
                    p = os.path.join(dp, f); m = modname(crate, p)
                    if m is not None: files[m] = p
        mods = set(files)
        edges = {m: set() for m in mods}
        for m, p in files.items():
            s = strip(open(p).read()); spans, _ = test_spans(s)
            for u in re.finditer(r'\b((?:crate|super|self)(?:::\w+)+)', s):
                if in_spans(u.start(), spans): continue
                t = resolve(mods, m, u.group(1))
                if t is not None and t != m and not m.startswith(t + '::') and t != '': edges[m].add(t)
            # a child module named without a prefix (`params::X`, `pub use params::X`)
            for u in re.finditer(r'(?<![:\w])(\w+)::', s):
                if in_spans(u.start(), spans): continue
                child = (m + '::' if m else '') + u.group(1)
                if child in mods: edges[m].add(child)
            # use super::{a, b} / use crate::{a::x, b}
            for u in re.finditer(r'\b(crate|super)::\{([^}]*)\}', s):
                if in_spans(u.start(), spans): continue
                for item in u.group(2).split(','):
                    item = item.strip().split(' ')[0]
                    if not item: continue
                    t = resolve(mods, m, u.group(1) + '::' + item)
                    if t is not None and t != m and not m.startswith(t + '::') and t != '': edges[m].add(t)
        # Tarjan
        idx = {}; low = {}; st = []; on = set(); out = []; c = [0]
        sys.setrecursionlimit(10000)
        def sc(v):
            idx[v] = low[v] = c[0]; c[0] += 1; st.append(v); on.add(v)
            for w in edges[v]:
                if w not in idx: sc(w); low[v] = min(low[v], low[w])
                elif w in on: low[v] = min(low[v], idx[w])
            if low[v] == idx[v]:
                comp = []
                while True:
                    w = st.pop(); on.discard(w); comp.append(w)
                    if w == v: break
                if len(comp) > 1: out.append(sorted(comp))
        for v in sorted(mods):
            if v not in idx: sc(v)
        for comp in out: print(crate, comp)


if __name__ == '__main__':
    cmd = sys.argv[1] if len(sys.argv) > 1 else ''
    if cmd == 'long-fns':
        limit = int(sys.argv[2]) if len(sys.argv) > 2 else 120
        found = []
        for c in CRATES:
            tf = test_files(c)
            found += [f for p in files(c) if p not in tf for f in functions(p)]
        for n, f, line, name in sorted(found, reverse=True):
            if n > limit:
                print(n, f'{f}:{line}', name)
    elif cmd == 'loc':
        tot = {c: sum(loc(p) for p in files(c) if p not in test_files(c)) for c in CRATES}
        total = sum(tot.values())
        for c, n in sorted(tot.items(), key=lambda kv: -kv[1]):
            print(f'{c:14s} {n:6d} {100 * n / total:5.1f} %')
        print('total', total)
    elif cmd == 'cycles':
        cycles()
    else:
        sys.exit(__doc__)
