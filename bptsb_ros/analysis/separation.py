"""How well a set of outputs separates the labels (the paper's PCA argument, Fig. 2(c), made a number).

* ``pca_2d``: the 2-D principal-component projection the figure shows (scikit-learn PCA of the raw features).
* ``silhouette``: the mean silhouette coefficient of the points grouped by label, in [−1, 1]; 1 = every point
  far closer to its own label's points than to any other label's, 0 = labels overlap. ``silhouette_per_label``:
  the mean over each label's points.
* ``probe_accuracy``: a linear probe: multinomial logistic regression on the standardised features, fitted
  on one half of the points and scored on the other (:func:`held_out`: stratified by label when every label has
  two points), the share of correctly labelled held-out points.
* ``label_spread``: how far each label's points lie from their label's mean (RMS radius) against the distance
  from that mean to the nearest other label's mean: whether a label's outputs are one point.
"""

from __future__ import annotations

import numpy as np


def pca_2d(features: np.ndarray) -> np.ndarray:
    """(n, f) → (n, 2) projection on the first two principal components."""
    from sklearn.decomposition import PCA

    return PCA(n_components=2).fit_transform(np.asarray(features, dtype=np.float64))


def silhouette(points: np.ndarray, labels: np.ndarray) -> float:
    """Mean silhouette coefficient (Euclidean) of ``points`` (n, f) grouped by ``labels`` (n,); NaN for fewer than
    two labels."""
    from sklearn.metrics import silhouette_score

    if len(np.unique(labels)) < 2:
        return float("nan")
    return float(silhouette_score(points, labels))


def silhouette_per_label(points: np.ndarray, labels: np.ndarray, n_labels: int = 10) -> np.ndarray:
    """(n_labels,) mean silhouette coefficient of each label's points (a lone point of its label scores 0); NaN
    for a label with no point, and everywhere for fewer than two labels."""
    from sklearn.metrics import silhouette_samples

    labels = np.asarray(labels)
    out = np.full(n_labels, np.nan)
    if len(np.unique(labels)) < 2:
        return out
    s = silhouette_samples(points, labels)
    for d in range(n_labels):
        if (labels == d).any():
            out[d] = float(s[labels == d].mean())
    return out


def held_out(labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """Sorted indices of the half of the points a probe is scored on (the other half fits it): ⌈n/2⌉ points,
    stratified by label when every label present has at least two points."""
    from sklearn.model_selection import train_test_split

    labels = np.asarray(labels)
    counts = np.bincount(labels)
    stratify = labels if counts[counts > 0].min() >= 2 else None
    _, test = train_test_split(np.arange(len(labels)), test_size=0.5, random_state=seed, stratify=stratify)
    return np.sort(test)


def probe_accuracy(features: np.ndarray, labels: np.ndarray, seed: int = 0) -> float:
    """Held-out accuracy of a linear probe (logistic regression on standardised inputs) fitted on the points
    outside :func:`held_out` and scored on those inside it; NaN when the fitting half holds fewer than two labels."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    features, labels = np.asarray(features, dtype=np.float64), np.asarray(labels)
    test = np.zeros(len(labels), dtype=bool)
    test[held_out(labels, seed)] = True
    if len(np.unique(labels[~test])) < 2:
        return float("nan")
    model = make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000))
    model.fit(features[~test], labels[~test])
    return float(model.score(features[test], labels[test]))


def separation_scores(features: np.ndarray, labels: np.ndarray, seed: int = 0) -> dict[str, float | np.ndarray]:
    """PCA to 2-D and the scores: on the projection the figure shows ``silhouette_2d``, ``per_label_2d`` (10,) and
    ``probe_2d``; on the standardised full features ``silhouette_full`` and ``probe_accuracy``; ``probe_n`` (points
    a probe is scored on) and ``probe_chance`` (the most common label's share among them); plus ``points_2d``."""
    from sklearn.preprocessing import StandardScaler

    features = np.asarray(features, dtype=np.float64)
    labels = np.asarray(labels)
    pts = pca_2d(features)
    full = StandardScaler().fit_transform(features)
    test = held_out(labels, seed)
    return {"points_2d": pts, "silhouette_2d": silhouette(pts, labels),
            "per_label_2d": silhouette_per_label(pts, labels), "probe_2d": probe_accuracy(pts, labels, seed),
            "silhouette_full": silhouette(full, labels), "probe_accuracy": probe_accuracy(features, labels, seed),
            "probe_n": len(test), "probe_chance": float(np.bincount(labels[test]).max() / len(test))}


def label_spread(features: np.ndarray, labels: np.ndarray, n_labels: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(radius, gap), each (n_labels,), in the features' unit: ``radius[d]`` the RMS distance of label d's points
    from their mean, √(mean_i ‖x_i − μ_d‖²); ``gap[d]`` the distance from μ_d to the nearest other label's mean
    (Euclidean, all features). NaN for a label with fewer than two points (one point has no spread to tell),
    and its mean is left out of the others' gaps; a gap is NaN when no other label has two points."""
    x = np.asarray(features, dtype=np.float64).reshape(len(labels), -1)
    labels = np.asarray(labels)
    radius, gap = np.full(n_labels, np.nan), np.full(n_labels, np.nan)
    present = [d for d in range(n_labels) if np.count_nonzero(labels == d) >= 2]
    if not present:
        return radius, gap
    means = np.stack([x[labels == d].mean(0) for d in present])
    for i, d in enumerate(present):
        radius[d] = float(np.sqrt(((x[labels == d] - means[i]) ** 2).sum(1).mean()))
    dist = np.linalg.norm(means[:, None] - means[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    if len(present) > 1:
        gap[present] = dist.min(1)
    return radius, gap
