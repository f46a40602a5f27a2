"""How well a set of outputs separates the labels (the paper's PCA argument, Fig. 2(c), made a number).

* ``pca_2d``: the 2-D principal-component projection the figure shows (scikit-learn PCA).
* ``silhouette``: the mean silhouette coefficient of the points grouped by label, in [−1, 1]; 1 = every point
  far closer to its own label's points than to any other label's, 0 = labels overlap.
* ``probe_accuracy``: a linear probe: multinomial logistic regression on the standardised features, fitted
  on one half of the points and scored on the other (stratified), the share of correctly labelled points.
"""

from __future__ import annotations

import numpy as np


def pca_2d(features: np.ndarray) -> np.ndarray:
    """(n, f) → (n, 2) projection on the first two principal components."""
    from sklearn.decomposition import PCA

    return PCA(n_components=2).fit_transform(np.asarray(features, dtype=np.float64))


def silhouette(points: np.ndarray, labels: np.ndarray) -> float:
    """Mean silhouette coefficient (Euclidean) of ``points`` (n, f) grouped by ``labels`` (n,)."""
    from sklearn.metrics import silhouette_score

    if len(np.unique(labels)) < 2:
        return float("nan")
    return float(silhouette_score(points, labels))


def probe_accuracy(features: np.ndarray, labels: np.ndarray, seed: int = 0) -> float:
    """Held-out accuracy of a linear probe (logistic regression, standardised inputs, half/half split)."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import train_test_split
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    counts = np.bincount(labels)
    stratify = labels if counts[counts > 0].min() >= 2 else None
    xa, xb, ya, yb = train_test_split(features, labels, test_size=0.5, random_state=seed, stratify=stratify)
    model = make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000))
    model.fit(xa, ya)
    return float(model.score(xb, yb))


def separation_scores(features: np.ndarray, labels: np.ndarray, seed: int = 0) -> dict[str, float | np.ndarray]:
    """PCA to 2-D and the three scores: ``silhouette_2d`` (on the projection the figure shows),
    ``silhouette_full`` (standardised full features) and ``probe_accuracy``; plus ``points_2d``."""
    from sklearn.preprocessing import StandardScaler

    features = np.asarray(features, dtype=np.float64)
    pts = pca_2d(features)
    full = StandardScaler().fit_transform(features)
    return {"points_2d": pts, "silhouette_2d": silhouette(pts, labels), "silhouette_full": silhouette(full, labels),
            "probe_accuracy": probe_accuracy(features, labels, seed)}
