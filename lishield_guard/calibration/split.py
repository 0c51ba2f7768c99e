"""The tuning / certification split: source groups, strata and a seeded, balanced split.
"""

from __future__ import annotations

import os
import re

import numpy as np

# ----------------------------------------------------------------------------- split


# Manifest fields that name the source photo an image was made from. First tier: an explicit
# group, a checksum, id or path of the source file (build_clean_set.py's real-photo variants:
# ``source_sha256``, ``source_path``), the scene of a synthetic capture (synth's ``scene_name``,
# ``scene_photo``, ``scene: {"scene": ..}``). Second tier, read only when the first names
# nothing, as these fields mean different things in different manifests: ``source`` (a
# scikit-image photo's name in build_clean_set.py's photo variants, but the package of its
# real-photo variants and the registry in the corpus manifest) and the corpus's own ``sha256``.
SOURCE_FIELDS = ("group", "source_group", "source_sha256", "source_id", "source_path",
                 "source_file", "source_photo", "scene_name", "scene_photo", "scene")
SOURCE_FIELDS_GENERIC = ("source", "photo", "sha256")
# values that name where a photo came from, not which photo (the corpus manifest's ``source``)
NOT_A_SOURCE = frozenset({"debian", "pypi", "skimage", "synth", "photo", "real-photo"})
# scikit-image names of one photograph (the stereo pair's two views are one scene)
SOURCE_ALIASES = {"stereo_motorcycle_left": "motorcycle", "stereo_motorcycle_right": "motorcycle",
                  "stereo_motorcycle": "motorcycle"}
_IMAGE_SUFFIX = re.compile(r"\.(jpe?g|png|webp|tiff?|bmp|heic|heif|gif)$", re.IGNORECASE)
# file-name suffixes that mark a variant of one source: "cat__crop2", "cat_v3", "cat-rot90"
_VARIANT_SUFFIX = re.compile(
    r"(?:__.*|[_-](?:v|var|variant|crop|aug|rot|q|scale|down|copy)\d+(?:\.\d+)?)+$")


def source_keys(row: dict, path: str) -> tuple[str, ...]:
    """Every name of the source photo an image was made from, as found in its manifest row.

    Parameters
    ----------
    row : dict
        The image's manifest row (may be empty).
    path : str
        The image's path.

    Returns
    -------
    tuple of str
        One key per `SOURCE_FIELDS` entry present (or, if none, per `SOURCE_FIELDS_GENERIC`
        entry), lower-cased: a path or file name is reduced to its base name without image
        extension, a ``skimage:`` prefix is dropped and `SOURCE_ALIASES` applied, so a
        scikit-image photo variant (``source: astronaut``), a synthetic capture of the same
        photo (``scene: skimage:astronaut``), and a corpus photo's variant (``source_path:
        usr/share/a.jpg``) and synthetic capture (``scene_photo:
        out/photos/images/debian/pkg/usr__share__a.jpg``) share a key. Procedural scenes
        (``texture:...``) and registry names (`NOT_A_SOURCE`, the corpus manifest's ``source:
        debian``) name no source. Without any, a file name ending in a variant marker
        (``__anything``, ``_v3``, ``-crop2``, ``_rot90``, ``_q85``) gives its stem, else the
        image is its own source (its absolute path).

    Examples
    --------
    >>> source_keys({"source": "astronaut"}, "photos/000001.jpg")
    ('src:astronaut',)
    >>> source_keys({"source": "hugin-data", "source_path": "usr/share/hugin/Lake.jpg",
    ...              "source_sha256": "AB12"}, "realphotos/000001.jpg")
    ('src:ab12', 'src:lake')
    >>> source_keys({"scene": {"scene": "skimage:astronaut"}}, "synth/000007.jpg")
    ('src:astronaut',)
    >>> source_keys({}, "clean/cat__crop2.jpg")
    ('name:cat',)
    """
    keys = _named_sources(row, SOURCE_FIELDS) or _named_sources(row, SOURCE_FIELDS_GENERIC)
    if keys:
        return keys
    stem = os.path.splitext(os.path.basename(str(path)))[0].lower()
    base = _VARIANT_SUFFIX.sub("", stem)
    if base and base != stem:
        return ("name:" + base,)
    return ("file:" + os.path.abspath(str(path)),)


def _named_sources(row: dict, names: tuple[str, ...]) -> tuple[str, ...]:
    keys = []
    for field_name in names:
        value = row.get(field_name)
        if isinstance(value, dict):
            value = value.get("scene")
        if value is None or str(value).strip() == "":
            continue
        value = str(value).strip().lower()
        if value.startswith("texture:") or value in NOT_A_SOURCE:
            continue  # a fresh random render per image, or a registry: no shared photo
        value = value.removeprefix("skimage:")
        if "/" in value or "\\" in value or _IMAGE_SUFFIX.search(value):
            # the corpus stores "a/b/c.jpg" as "a__b__c.jpg": both reduce to "c"
            value = value.replace("\\", "/").replace("__", "/")
            value = _IMAGE_SUFFIX.sub("", value.rsplit("/", 1)[-1])
        value = SOURCE_ALIASES.get(value, value)
        if value and "src:" + value not in keys:
            keys.append("src:" + value)
    return tuple(keys)


def source_groups(keys: list[tuple[str, ...]]) -> list[str]:
    """Group label of each image: images sharing any source key, directly or through others,
    form one group (connected components), labelled by the group's smallest key.

    Parameters
    ----------
    keys : list of tuple of str
        Per image, its `source_keys`.

    Returns
    -------
    list of str
        Per image, its group label.

    Examples
    --------
    >>> source_groups([("src:a",), ("src:b", "src:c"), ("src:c",), ("src:a", "src:z")])
    ['src:a', 'src:b', 'src:b', 'src:a']
    """
    parent: dict[str, str] = {}

    def find(k: str) -> str:
        parent.setdefault(k, k)
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for ks in keys:
        roots = sorted({find(k) for k in ks})
        for r in roots[1:]:
            parent[r] = roots[0]
    return [find(ks[0]) for ks in keys]


def stratum_key(row: dict, origin: str) -> str:
    """Stratum of an image for the split: its origin (input folder), kind, preset and package.

    Parameters
    ----------
    row : dict
        Manifest row: ``kind`` (photo, steady, mains, pwm, texture, barcode), ``preset`` for
        positives, ``package`` for photos of the real-photo corpus (and sets made from it).
        Missing fields read as "-"; a missing package is left out.
    origin : str
        Where the image came from, e.g. the input folder's name.

    Examples
    --------
    >>> stratum_key({"kind": "mains"}, "synth")
    'synth/mains/-'
    >>> stratum_key({"package": "hugin-data"}, "photos")
    'photos/-/-/hugin-data'
    """
    key = f"{origin}/{row.get('kind') or '-'}/{row.get('preset') or '-'}"
    return f"{key}/{row['package']}" if row.get("package") else key


def split_parts(groups: list[str], strata: list[str], *, fraction: float, seed: int
                ) -> np.ndarray:
    """Seeded, stratified split into a tuning and a certification part, whole groups at a time.

    Parameters
    ----------
    groups : list of str
        Per item, its `source_groups` label; every item of a group goes to the same part.
    strata : list of str
        Per item, its `stratum_key`; each stratum is split about ``fraction`` : 1 - fraction.
    fraction : float
        Target share of the certification part, in (0, 1), unitless.
    seed : int
        Split seed; the result depends only on (groups, strata, fraction, seed), not on the
        order of the items.

    Returns
    -------
    ndarray of bool, shape (n_items,)
        True for items of the certification part.

    Raises
    ------
    ValueError
        If ``fraction`` is outside (0, 1) or the lists differ in length.

    Notes
    -----
    Groups are visited largest first (ties in a seeded random order); each goes to the part that
    keeps the running per-stratum counts closest, in squared count, to ``fraction`` of the items
    assigned so far (a tie is broken by a seeded draw with probability ``fraction``). With many
    small groups every stratum ends within about one group of its target; a group larger than
    a stratum's share cannot be split and is not.

    Examples
    --------
    >>> split_parts(["a", "a", "b", "c"], ["x"] * 4, fraction=0.5, seed=0).tolist()
    [True, True, False, False]
    """
    if not 0 < fraction < 1:
        raise ValueError(f"need 0 < fraction < 1, got fraction={fraction!r}")
    if len(groups) != len(strata):
        raise ValueError(f"need one stratum per item, got {len(groups)} groups and "
                         f"{len(strata)} strata")
    g_names = sorted(set(groups))
    s_names = sorted(set(strata))
    g_index = {g: i for i, g in enumerate(g_names)}
    s_index = {s: i for i, s in enumerate(s_names)}
    g_of = np.array([g_index[g] for g in groups], dtype=int)
    counts = np.zeros((len(g_names), len(s_names)))
    np.add.at(counts, (g_of, [s_index[s] for s in strata]), 1)
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(g_names))
    order = order[np.argsort(-counts[order].sum(axis=1), kind="stable")]
    cert_counts = np.zeros(len(s_names))
    seen = np.zeros(len(s_names))
    to_cert = np.zeros(len(g_names), dtype=bool)
    for g in order:
        c = counts[g]
        goal = fraction * (seen + c)
        cost_cert = float(np.sum((cert_counts + c - goal) ** 2))
        cost_tune = float(np.sum((cert_counts - goal) ** 2))
        draw = rng.random() < fraction
        if cost_cert < cost_tune - 1e-9 or (abs(cost_cert - cost_tune) <= 1e-9 and draw):
            to_cert[g] = True
            cert_counts += c
        seen += c
    return to_cert[g_of]
