#!/usr/bin/env python3
"""The code's size and shape limits: files over 1 000 lines, functions of 150 lines or more
outside tests, and import cycles between the files of a crate.

How it counts:
- a file: its lines (`wc -l`), tests included;
- a function: from the line of its `fn` keyword to the line of its closing brace, blank lines
  and comments included; functions under `tests/`, `benches/`, in `tests.rs` files and in
  `#[cfg(test)]` modules are left out; strings, chars and comments are blanked before braces
  are matched;
- an import edge a -> b: a's code (comments, strings and test modules left out) names an item
  that b defines, by a path (`crate::m::X`, `super::X`, `self::m::X`, a child module's name),
  through a glob of b, or through re-exports that lead to b. A re-export itself is no edge (a
  facade is not a dependency), and neither is a file's use of its own ancestor module (a child
  module is part of its parent: impl blocks of the parent's type). A cycle is a strongly
  connected set of two or more files.

`python3 scripts/code-limits.py` prints what breaks the limits; `--strict` exits 1 then.
"""
import re, sys, os

def strip(src):
    # blank out strings, chars and comments, keep newlines
    out=[]; i=0; n=len(src)
    while i<n:
        c=src[i]
        if src.startswith('//',i):
            j=src.find('\n',i); j=n if j<0 else j
            out.append(' '*(j-i)); i=j; continue
        if src.startswith('/*',i):
            depth=1; j=i+2
            while j<n and depth:
                if src.startswith('/*',j): depth+=1; j+=2
                elif src.startswith('*/',j): depth-=1; j+=2
                else: j+=1
            out.append(re.sub(r'[^\n]',' ',src[i:j])); i=j; continue
        m=re.match(r'b?r(#*)"',src[i:i+10])
        if m and (i==0 or not (src[i-1].isalnum() or src[i-1]=='_')):
            hashes=m.group(1); end='"'+hashes
            j=src.find(end,i+len(m.group(0)))
            j=n if j<0 else j+len(end)
            out.append(re.sub(r'[^\n]',' ',src[i:j])); i=j; continue
        if c=='"':
            j=i+1
            while j<n and src[j]!='"':
                j+= 2 if src[j]=='\\' else 1
            j+=1
            out.append(re.sub(r'[^\n]',' ',src[i:j])); i=j; continue
        if c=="'":
            m=re.match(r"'(\\.|\\u\{[0-9a-fA-F]+\}|\\x..|[^\\'])'",src[i:i+12])
            if m:
                out.append(' '*len(m.group(0))); i+=len(m.group(0)); continue
        out.append(c); i+=1
    return ''.join(out)

def functions(path):
    src=open(path).read()
    s=strip(src)
    lines=s.split('\n')
    # test module ranges
    res=[]
    test_ranges=[]
    for m in re.finditer(r'#\[cfg\(test\)\]\s*(pub\s+)?mod\s+\w+\s*\{', s):
        start=m.end()-1; depth=0
        for j in range(start,len(s)):
            if s[j]=='{': depth+=1
            elif s[j]=='}':
                depth-=1
                if depth==0: test_ranges.append((m.start(),j)); break
    for m in re.finditer(r'\bfn\s+(\w+)', s):
        pos=m.end()
        if any(a<=pos<=b for a,b in test_ranges): continue
        # find body start: first '{' or ';' at depth 0 of parens/angles
        j=pos; par=0
        while j<len(s):
            ch=s[j]
            if ch in '([': par+=1
            elif ch in ')]': par-=1
            elif ch==';' and par==0: j=-1; break
            elif ch=='{' and par==0: break
            j+=1
        if j<0 or j>=len(s): continue
        depth=0; k=j
        while k<len(s):
            if s[k]=='{': depth+=1
            elif s[k]=='}':
                depth-=1
                if depth==0: break
            k+=1
        l0=s.count('\n',0,m.start())+1; l1=s.count('\n',0,k)+1
        res.append((l1-l0+1,m.group(1),l0))
    return res


ITEM = re.compile(r'^\s*(?:pub(?:\([\w:]+\))?\s+)?(?:async\s+)?(?:unsafe\s+)?(?:fn|struct|enum|const|type|static|trait|macro_rules!|union)\s+(\w+)', re.M)
MOD = re.compile(r'^\s*(?:pub(?:\([\w:]+\))?\s+)?mod\s+(\w+)\s*;', re.M)

def crate_graph(src):
    files = [os.path.join(r, f) for r, _, fs in os.walk(src) for f in fs if f.endswith('.rs')]
    def modpath(f):
        rel = os.path.relpath(f, src)[:-3].split(os.sep)
        if rel[-1] in ('mod', 'lib'): rel = rel[:-1]
        return tuple(rel)
    byp = {modpath(f): f for f in files}
    text = {}
    for f in files:
        s = strip(open(f).read())
        s = re.sub(r'#\[cfg\(test\)\]\s*(pub\s+)?mod\s+\w+\s*;', '', s)
        s = re.sub(r'#\[cfg\(test\)\]\s*mod\s+\w+\s*\{(?:[^{}]|\{(?:[^{}]|\{(?:[^{}]|\{(?:[^{}]|\{[^{}]*\})*\})*\})*\})*\}', '', s)
        text[f] = s
    defs = {f: set(ITEM.findall(text[f])) for f in files}
    # use declarations: (file, is_pub, path tuple, name-or-*)
    uses = {f: [] for f in files}
    for f in files:
        me = modpath(f)
        for m in re.finditer(r'^\s*(pub(?:\([\w:]+\))?\s+)?use\s+([^;]+);', text[f], re.M):
            is_pub = bool(m.group(1))
            for p in expand(m.group(2)):
                uses[f].append((is_pub, resolve(me, p, byp, f), p[-1]))
    def target(path, name, seen=()):
        """The file that defines `name` reached through module `path` (following re-exports)."""
        f = byp.get(tuple(path))
        if f is None or (f, name) in seen: return None
        if name in defs[f] or name == '*': return f
        for is_pub, p, n in uses[f]:
            if n == name or n.endswith(' as ' + name):
                return target(p[:-1], n.split(' as ')[0], seen + ((f, name),)) if p else None
            if n == '*' and p:
                t = target(p[:-1], name, seen + ((f, name),))
                if t: return t
        return f
    g = {f: set() for f in files}
    for f in files:
        me = modpath(f)
        # through use declarations (not re-exports)
        for is_pub, p, n in uses[f]:
            if is_pub or not p: continue
            name = n.split(' as ')[0]
            if name == '*':
                t = byp.get(tuple(p[:-1]))
                if t: g[f].add(t)
                continue
            t = target(p[:-1], name) if tuple(p[:-1]) in byp else None
            if t is None and tuple(p) in byp: t = byp[tuple(p)]
            if t: g[f].add(t)
        # inline paths in code
        for m in re.finditer(r'\b(crate|super|self)((?:::\w+)+)', text[f]):
            if re.match(r'\s*(pub(\([\w:]+\))?\s+)?use\b', text[f][text[f].rfind('\n', 0, m.start())+1:m.start()]):
                continue
            p = resolve(me, (m.group(1),) + tuple(m.group(2).strip(':').split('::')), byp, f)
            if not p: continue
            # longest module prefix
            for k in range(len(p), -1, -1):
                if tuple(p[:k]) in byp:
                    mod = tuple(p[:k]); rest = p[k:]
                    break
            t = target(mod, rest[0]) if rest else byp[mod]
            if t: g[f].add(t)
        g[f].discard(f)
        # A file's use of its own ancestors (the module it is part of) is the module tree, not
        # an import: a child extends its parent (impl blocks of the parent's type).
        for t in list(g[f]):
            tp = modpath(t)
            if len(tp) < len(me) and me[:len(tp)] == tp:
                g[f].discard(t)
    return g, byp

def expand(tree):
    # `X as Y` keeps X, the name that is defined somewhere.
    tree = re.sub(r'\s+as\s+\w+', '', tree)
    tree = re.sub(r'\s+', '', tree)
    def rec(prefix, t):
        if '{' not in t:
            return [prefix + tuple(t.split('::'))]
        i = t.index('{')
        head = t[:i].rstrip(':')
        body = t[i+1:t.rindex('}')]
        parts, depth, cur = [], 0, ''
        for ch in body:
            if ch == ',' and depth == 0:
                parts.append(cur); cur = ''
                continue
            depth += ch == '{'; depth -= ch == '}'
            cur += ch
        parts.append(cur)
        base = prefix + (tuple(head.split('::')) if head else ())
        out = []
        for p in parts:
            if p: out += rec(base, p)
        return out
    return rec((), tree)

def resolve(me, p, byp, f):
    is_modfile = f.endswith(('mod.rs', 'lib.rs'))
    p = list(p)
    if p[0] == 'crate': return tuple(p[1:])
    if p[0] == 'self': return tuple(me) + tuple(p[1:])
    if p[0] == 'super':
        base = list(me)
        while p and p[0] == 'super':
            base = base[:-1]; p = p[1:]
        return tuple(base) + tuple(p)
    if tuple(me) + (p[0],) in byp: return tuple(me) + tuple(p)
    return None  # an external crate

def sccs(g):
    idx, low, st, on, out, c = {}, {}, [], set(), [], [0]
    sys.setrecursionlimit(100000)
    def sc(v):
        idx[v] = low[v] = c[0]; c[0] += 1; st.append(v); on.add(v)
        for w in g[v]:
            if w not in idx: sc(w); low[v] = min(low[v], low[w])
            elif w in on: low[v] = min(low[v], idx[w])
        if low[v] == idx[v]:
            comp = []
            while True:
                w = st.pop(); on.discard(w); comp.append(w)
                if w == v: break
            if len(comp) > 1: out.append(comp)
    for v in g:
        if v not in idx: sc(v)
    return out


def main():
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--max-fn-lines', type=int, default=150)
    ap.add_argument('--max-file-lines', type=int, default=1000)
    ap.add_argument('--strict', action='store_true', help='exit 1 when a limit is broken')
    a = ap.parse_args()
    os.chdir(os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))
    long_files, long_fns = [], []
    for root, _, files in os.walk('crates'):
        for f in files:
            if not f.endswith('.rs'):
                continue
            p = os.path.join(root, f)
            n = sum(1 for _ in open(p))
            if n > a.max_file_lines:
                long_files.append((n, p))
            if '/tests/' in p or '/benches/' in p or f == 'tests.rs':
                continue
            for ln, name, l0 in functions(p):
                if ln >= a.max_fn_lines:
                    long_fns.append((ln, f"{p}:{l0}", name))
    for n, p in sorted(long_files, reverse=True):
        print(f"file {n:5d} lines  {p}")
    for ln, p, name in sorted(long_fns, reverse=True):
        print(f"fn   {ln:5d} lines  {p} {name}")
    cycles = 0
    for crate in sorted(os.listdir('crates')):
        src = os.path.join('crates', crate, 'src')
        if not os.path.isdir(src):
            continue
        g, _ = crate_graph(src)
        for comp in sccs(g):
            cycles += 1
            print(f"cycle in {crate}: " + ', '.join(sorted(os.path.relpath(x, src) for x in comp)))
    print(f"{len(long_files)} files over {a.max_file_lines} lines, {len(long_fns)} functions of "
          f"{a.max_fn_lines} lines or more outside tests, {cycles} import cycles between files")
    broken = long_files or long_fns or cycles
    sys.exit(1 if a.strict and broken else 0)


if __name__ == '__main__':
    main()
