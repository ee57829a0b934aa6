#!/usr/bin/env python3
"""Checks every relative link and #anchor in the built book (mdBook does not check them).

    mdbook build docs && python3 scripts/check-book-links.py [BOOK_DIR]

BOOK_DIR defaults to target/book (docs/book.toml's build-dir). README.md's relative links into
the repository (the book's chapters, the design notes, the screenshot) are checked too: a file
each must name. A link is broken when the file
it names does not exist in the built book, or when its #anchor is no id of the page it points
to. Links with a scheme (https:, mailto:) are not followed: CI has no internet, and a page
elsewhere is not the book's to keep. Exits 1 and lists every broken link.
"""

import re
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

ROOT = Path(__file__).resolve().parent.parent


class Page(HTMLParser):
    """The ids a page defines and the links it makes (tag, attribute, value)."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.ids = set()
        self.links = []

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k in ("id", "name") and v:
                self.ids.add(v)
            if v is not None and (k, tag) in (("href", "a"), ("src", "img"), ("href", "link"),
                                              ("src", "script")):
                self.links.append(v)


def parse(path, cache={}):
    if path not in cache:
        p = Page()
        p.feed(path.read_text(errors="replace"))
        cache[path] = p
    return cache[path]


def main():
    book = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "target/book"
    pages = sorted(book.rglob("*.html"))
    if not pages:
        sys.exit(f"check-book-links: no HTML under {book}: run `mdbook build docs` first")
    broken = []
    checked = 0
    for page in pages:
        for link in parse(page).links:
            u = urlsplit(link)
            if u.scheme or u.netloc or link.startswith("//"):
                continue
            target = (page.parent / unquote(u.path)).resolve() if u.path else page
            if target.is_dir():
                target = target / "index.html"
            checked += 1
            rel = page.relative_to(book)
            if not target.exists():
                broken.append(f"{rel}: {link}: no such file in the book")
                continue
            if u.fragment and target.suffix == ".html" and unquote(u.fragment) not in parse(target).ids:
                broken.append(f"{rel}: {link}: no #{u.fragment} on {target.relative_to(book)}")
    for link in re.findall(r"\]\(([^)\s]+)\)", (ROOT / "README.md").read_text()):
        u = urlsplit(link)
        if u.scheme or not u.path:
            continue
        checked += 1
        if not (ROOT / unquote(u.path)).exists():
            broken.append(f"README.md: {link}: no such file in the repository")
    for b in broken:
        print(b)
    print(f"check-book-links: {len(pages)} pages, {checked} relative links, {len(broken)} broken")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
