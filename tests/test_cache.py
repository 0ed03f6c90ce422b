"""On-disk render cache: hits, corrupt entries re-rendered, concurrent writers."""
import multiprocessing as mp

import numpy as np
import torch

import nlosbench as nb
from nlosbench.forward.cache import RenderCache, render_key


def test_cache_hit_returns_same_image_without_rendering(tmp_path, cornell):
    cornell.cache = RenderCache(tmp_path)
    try:
        a = cornell.render([0.1, 0.3, 0.8], 16, 9)
        n = cornell.stats.renders
        b = cornell.render([0.1, 0.3, 0.8], 16, 9)
        assert cornell.stats.renders == n and cornell.cache.hits == 1 and torch.equal(a, b)
        cornell.render([0.1, 0.3, 0.8], 16, 10)  # another seed is another key
        assert cornell.stats.renders == n + 1
    finally:
        cornell.cache = None


def test_corrupt_or_truncated_entry_is_rerendered(tmp_path):
    m = nb.scenes.get("blob2d", render_noise=0.1, cache=str(tmp_path))
    a = m.render([0.5, 0.5], 4, 1)
    (entry,) = list(tmp_path.rglob("*.npc"))
    raw = entry.read_bytes()
    entry.write_bytes(raw[: len(raw) // 2])  # truncated
    b = m.render([0.5, 0.5], 4, 1)
    assert torch.equal(a, b) and m.cache.corrupt == 1 and m.stats.renders == 2
    entry.write_bytes(raw[:-4] + b"\x00\x00\x00\x01")  # flipped payload bytes
    assert torch.equal(m.render([0.5, 0.5], 4, 1), a) and m.cache.corrupt == 2


KEY = render_key(request="two writers")


def _writer(root, n):
    c = RenderCache(root)
    img = torch.arange(3 * 64 * 64, dtype=torch.float32).reshape(64, 64, 3)
    for _ in range(n):
        c.put(KEY, img)


def test_two_processes_writing_the_same_key(tmp_path):
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_writer, args=(str(tmp_path), 30)) for _ in range(2)]
    [p.start() for p in procs]
    [p.join() for p in procs]
    assert all(p.exitcode == 0 for p in procs)
    got = RenderCache(tmp_path).get(KEY)
    assert got is not None and np.array_equal(got.numpy().ravel(), np.arange(3 * 64 * 64))
    assert not [f for f in tmp_path.rglob(".*") if f.is_file()]  # no temporary files left


def test_scene_hash_covers_included_and_referenced_files(tmp_path):
    """The cache key's scene hash changes when a file the scene includes or loads changes: a mesh named
    through a define (its default, then a value passed), one inside an included file, the include itself."""
    from nlosbench.forward.scene_files import content_hash, scene_files

    main = tmp_path / "main.xml"
    main.write_text('<scene version="3.0.0"><default name="mesh" value="a"/><include filename="part.xml"/>'
                    '<shape type="obj"><string name="filename" value="$mesh.obj"/></shape></scene>')
    (tmp_path / "part.xml").write_text('<scene version="3.0.0"><shape type="obj">'
                                       '<string name="filename" value="inner.obj"/></shape></scene>')
    for name in ("a", "b", "inner"):
        (tmp_path / f"{name}.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert sorted(scene_files(main, {}, "scalar_rgb")) == ["a.obj", "inner.obj", "main.xml", "part.xml"]

    def h(**defines):
        return content_hash(main, defines, "scalar_rgb")

    seen = [h(), h(mesh="b")]
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")
    seen += [h(), h(mesh="b")]
    (tmp_path / "inner.obj").write_text("v 0 0 0\nv 3 0 0\nv 0 1 0\nf 1 2 3\n")
    seen.append(h())
    assert len(set(seen)) == 4 and seen[1] == seen[3]  # b.obj untouched: the same hash with mesh=b


def test_render_keys_hold_the_rendering_code_and_any_component_that_joins(monkeypatch):
    """Every render key holds `code`: a hash over forward/ and the package modules it imports (seeds.py: the
    pass seeds; not the studies). A component added to `keys.COMPONENTS` joins every key, and the key's
    fields (what a stored render carries) name it."""
    from nlosbench import sources
    from nlosbench.forward import keys

    files = sources.closure("forward")
    assert "forward/mitsuba_model.py" in files and "seeds.py" in files and "params.py" in files
    assert not [f for f in files if f.startswith(("studies/", "experiment/", "bounds/"))]
    before = render_key(theta=["0.5"], spp=4, seed=1)
    assert before.fields["code"] == sources.digest(files)
    monkeypatch.setitem(keys.COMPONENTS, "machine", lambda: {"isa": "test"})
    after = render_key(theta=["0.5"], spp=4, seed=1)
    assert after != before and after.fields["machine"] == {"isa": "test"}
