"""Shared Stan functions against numpy/scipy references (tolerance 1e-10)."""

from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from stancal.numerics.kernels import ard_cross_cov
from stancal.numerics.multifidelity import Level, level_covariance
from stancal.numerics.scalable_emulator import Hyperparameters
from stancal.problem.codes import Kernel
from stancal.stan.backends.pystan_compile import compile_programs
from stancal.stan.source import flatten

HARNESS = Path(__file__).parent / "stan" / "function_harness.stan"
rng = np.random.default_rng(3)
X1, X2 = rng.uniform(size=(6, 2)), rng.uniform(size=(4, 2))
SD, LS = 1.7, np.array([0.3, 0.8])
RESID = rng.standard_normal(6)
A_RESTRICT = rng.standard_normal((6, 2))
RIDGE = 0.3
# one observation per censoring code (observed, left, right, interval), and counts
OBSERVATIONS = {"eta": [0.3, -1.2, 2.0, 0.1], "y_real": [0.5, 0, 0, 0], "y_int": [3, 0, 12, 7],
                    "trials": [5, 4, 20, 9], "censoring": [0, 1, 2, 3], "lower_bound": [0, 0, 1.5, -0.4],
                    "upper_bound": [0, -0.8, 0, 0.9]}
X_SIM = rng.uniform(0.5, 2.0, size=(3, 2))
THETA_SIM, THETA_LO, THETA_HI = np.array([0.7, 1.3]), np.array([0.1, -1.0]), np.array([2.0, 3.0])
Z_DRAW = rng.standard_normal(4)
# noise.stan: two sources' sds, each point's source and known sd, mixture weights and nu
NOISE = {"source_sd": [0.3, 1.1], "source": [1, 2, 2, 1, 2, 1], "known_sd": [0.0, 0.5, 0.0, 0.2, 0.0, 0.7],
         "mix_weight": [1.2, 0.3, 0.9, 1.0, 0.05, 2.0], "nu": [4.5]}
# each point's noise variance, noise.stan's noise_variance of NOISE: the sds added in quadrature
# (Hogg, Bovy & Lang 2010)
NOISE_VAR = (np.array(NOISE["source_sd"])[np.array(NOISE["source"]) - 1] ** 2
             + np.array(NOISE["known_sd"]) ** 2)
JITTER = 1e-6  # of the prior variance: gp_kernels.stan's add_jitter


def se(a, b):
    d2 = (((a[:, None, :] - b[None, :, :]) / LS) ** 2).sum(-1)
    return SD**2 * np.exp(-0.5 * d2)


def matern52(a, b):
    r = np.sqrt((((a[:, None, :] - b[None, :, :]) / LS) ** 2).sum(-1))
    return SD**2 * (1 + np.sqrt(5) * r + 5 * r**2 / 3) * np.exp(-np.sqrt(5) * r)


def test_python_kernels_mirror_the_references():
    # stancal.numerics.kernels is checked here against the same references as Stan's
    assert np.allclose(ard_cross_cov(X1, X2, Kernel.SE, SD, LS), se(X1, X2), rtol=1e-12)
    assert np.allclose(ard_cross_cov(X1, X2, Kernel.MATERN52, SD, LS), matern52(X1, X2), rtol=1e-12)


@pytest.fixture(scope="module")
def gq():
    import stan

    data = dict(n1=6, n2=4, x1=X1.tolist(), x2=X2.tolist(), sd_=SD, ls=LS.tolist(),
                resid=RESID.tolist(), unit=[0, 0.5, 1], lo=[-1, 0, 10], hi=[1, 2, 20],
                A_restrict=A_RESTRICT.tolist(), ridge=RIDGE, X_sim=X_SIM.tolist(),
                theta_sim=THETA_SIM.tolist(), theta_lo=THETA_LO.tolist(), theta_hi=THETA_HI.tolist(),
                z_draw=Z_DRAW.tolist(), given_count=2, needed_count=2, **OBSERVATIONS, **NOISE)
    harness = flatten(HARNESS)
    compile_programs([harness])  # stancal's build: no debug information, and no 5-minute HTTP timeout
    model = stan.build(harness.code, data=data, random_seed=1)
    fit = model.fixed_param(num_samples=1, num_chains=1)
    out = {name: np.asarray(fit[name])[..., 0] for name in fit.param_names}
    out["_data"] = data
    return out


def test_squared_exponential(gq):
    np.testing.assert_allclose(gq["se_cross"], se(X1, X2), rtol=1e-10)
    np.testing.assert_allclose(gq["se_sym"], se(X1, X1), rtol=1e-10)


def test_the_squared_exponential_factorises_into_x_and_theta(gq):
    shared_theta = X1.copy()
    shared_theta[:, 1] = X1[0, 1]
    np.testing.assert_allclose(gq["se_cross_shared_theta"], se(shared_theta, X2), rtol=1e-10)


def test_matern52(gq):
    np.testing.assert_allclose(gq["m52_cross"], matern52(X1, X2), rtol=1e-10)
    np.testing.assert_allclose(gq["m52_sym"], matern52(X1, X1), rtol=1e-10, atol=1e-12)


def test_loo_log_lik_and_mean_match_brute_force_conditionals(gq):
    K = se(X1, X1) + 0.1 * np.eye(6)
    expected, means = [], []
    for i in range(6):
        rest = np.delete(np.arange(6), i)
        w = np.linalg.solve(K[np.ix_(rest, rest)], K[rest, i])
        mean = w @ RESID[rest]
        var = K[i, i] - K[i, rest] @ w
        expected.append(stats.norm.logpdf(RESID[i], mean, np.sqrt(var)))
        means.append(mean)
    np.testing.assert_allclose(gq["loo"], expected, rtol=1e-10)
    np.testing.assert_allclose(gq["loo_mean"], means, rtol=1e-10)


def test_gp_conditional_mean(gq):
    K = se(X1, X1) + 0.1 * np.eye(6)
    np.testing.assert_allclose(gq["conditional_mean"], se(X2, X1) @ np.linalg.solve(K, RESID), rtol=1e-10)


def test_gp_conditional_draw_from_given_normals(gq):
    K = se(X1, X1) + 0.1 * np.eye(6)
    A = np.linalg.solve(K, se(X1, X2))
    cov = se(X2, X2) - se(X2, X1) @ A
    cov += JITTER * np.mean(np.diag(se(X2, X2))) * np.eye(4)
    expected = A.T @ RESID + np.linalg.cholesky(cov) @ Z_DRAW
    np.testing.assert_allclose(gq["conditional_draw"], expected, rtol=1e-8)
    np.testing.assert_allclose(gq["given_normals"], Z_DRAW, rtol=0)
    assert gq["no_normals"].size == 0


def test_a_repeated_run_with_no_nugget_is_factorised_with_the_jitter(gq):
    points = np.vstack([X2, X2[:1]])
    K = se(points, points) + JITTER * SD**2 * np.eye(5)
    np.testing.assert_allclose(gq["repeated_runs_cholesky"], np.linalg.cholesky(K), rtol=1e-6, atol=1e-9)


def simulator_derivatives(theta):
    x1, x2 = X_SIM[:, 0], X_SIM[:, 1]
    return np.column_stack([-x1 * np.exp(-theta[0] * x1), x2**2])


def test_theta_derivatives_are_central_differences(gq):
    # central differences of step 1e-5 of the range: error ~1e-10; one-sided ones are off by ~1e-6
    np.testing.assert_allclose(gq["dfdtheta"], simulator_derivatives(THETA_SIM), rtol=1e-8)
    # at a bound the step stays inside the box (one-sided there), still accurate to ~1e-5
    np.testing.assert_allclose(gq["dfdtheta_at_bound"], simulator_derivatives(THETA_LO), rtol=1e-4)


def test_theta_from_unit(gq):
    np.testing.assert_allclose(gq["theta"], [-1, 1, 20])


def test_koh_joint_covariance(gq):
    rho, nugget, delta_sd, delta_ls = 1.3, 0.01, 0.7, np.array([0.4, 0.6])
    xt_obs = np.column_stack([X1[:, 0], np.full(6, 0.3)])
    K_ss = se(X2, X2) + nugget**2 * np.eye(4)
    K_so = rho * se(X2, xt_obs)
    d2 = (((X1[:, None, :] - X1[None, :, :]) / delta_ls) ** 2).sum(-1)
    K_oo = rho**2 * se(xt_obs, xt_obs) + delta_sd**2 * np.exp(-0.5 * d2) + np.diag(NOISE_VAR)
    expected = np.block([[K_ss, K_so], [K_so.T, K_oo]]) + JITTER * SD**2 * np.eye(10)
    np.testing.assert_allclose(gq["joint"], expected, rtol=1e-10)


def test_fidelity_covariance_is_the_numpy_co_kriging_one(gq):
    """functions/fidelity.stan against stancal.numerics.multifidelity, two levels, rho 1.7."""
    levels = [Level(Hyperparameters(0.0, SD, LS, 0.0), 1.0, X2[[0, 2]], np.zeros(2)),
              Level(Hyperparameters(0.0, 0.5, np.array([0.2, 0.9]), 0.0), 1.7, X2[[1, 3]], np.zeros(2))]
    np.testing.assert_allclose(gq["fidelity_w"], [[1, 0], [1.7, 1]])
    expected = np.empty((6, 4))
    expected[:, [0, 2]] = level_covariance(levels, X1, 1, X2[[0, 2]], 0)
    expected[:, [1, 3]] = level_covariance(levels, X1, 1, X2[[1, 3]], 1)
    np.testing.assert_allclose(gq["fidelity_cross"], expected, rtol=1e-10)


def test_fidelity_point_weights_are_the_numpy_scales_at_each_point(gq):
    """fidelity_point_weights against stancal.numerics.multifidelity's rho(x)
    (three levels, rho_k(x) = beta_0 + x' beta_x; Le Gratiet & Garnier 2014),
    and fidelity_widest, the row of the largest prior variance."""
    h = Hyperparameters(0.0, 1.0, LS, 0.0)
    levels = [Level(h, 1.0, X2, np.zeros(4)), Level(h, 1.7, X2, np.zeros(4), np.array([0.5, -0.4])),
              Level(h, 0.6, X2, np.zeros(4), np.array([-0.3, 0.9]))]
    # rho written out here, not through the code under test (Level.rho_at): 1.7 + x' (0.5, -0.4), 0.6 + x' (-0.3, 0.9)
    rho2, rho3 = 1.7 + X2[:, :2] @ [0.5, -0.4], 0.6 + X2[:, :2] @ [-0.3, 0.9]
    np.testing.assert_allclose([levels[1].rho_at(X2), levels[2].rho_at(X2)], [rho2, rho3], rtol=1e-12)
    expected = np.array([[1, 0, 0], [rho2[1], 1, 0], [rho2[2] * rho3[2], rho3[2], 1], [rho2[3] * rho3[3], rho3[3], 1]])
    np.testing.assert_allclose(gq["fidelity_point_w"], expected, rtol=1e-12)
    variance = (expected * [SD, 0.5, 0.2]) ** 2 @ np.ones(3)
    np.testing.assert_allclose(gq["fidelity_widest_w"], expected[variance.argmax()], rtol=1e-12)


def test_orthogonal_gp_covariance(gq):
    """K - K A (A'KA)^-1 A'K: the functionals A' delta have zero prior variance."""
    K = se(X1, X1)
    T = A_RESTRICT.T @ K @ A_RESTRICT
    T += JITTER * np.mean(np.diag(T)) * np.eye(2)
    expected = K - K @ A_RESTRICT @ np.linalg.solve(T, A_RESTRICT.T @ K)
    np.testing.assert_allclose(gq["orthogonal_cov"], expected, rtol=1e-7, atol=1e-10)
    # the functionals keep about the jitter's share of their prior variance
    np.testing.assert_allclose(A_RESTRICT.T @ gq["orthogonal_cov"] @ A_RESTRICT, 0,
                               atol=2 * JITTER * np.mean(np.diag(A_RESTRICT.T @ K @ A_RESTRICT)))


def test_scaled_gp_covariance(gq):
    """S-GaSP: K - K (K + ridge I)^-1 K, smaller than K in every direction."""
    K = se(X1, X1)
    T = K + (RIDGE + JITTER * np.mean(np.diag(K))) * np.eye(6)
    np.testing.assert_allclose(gq["scaled_cov"], K - K @ np.linalg.solve(T, K), rtol=1e-7, atol=1e-10)
    assert np.all(np.linalg.eigvalsh(K - gq["scaled_cov"]) > -1e-10)


def test_observation_models(gq):
    eta, sd = np.array(OBSERVATIONS["eta"]), 0.7
    lower, upper = OBSERVATIONS["lower_bound"], OBSERVATIONS["upper_bound"]
    censored = [stats.norm.logpdf(0.5, eta[0], sd), stats.norm.logcdf(upper[1], eta[1], sd),
                stats.norm.logsf(lower[2], eta[2], sd),
                np.log(stats.norm.cdf(upper[3], eta[3], sd) - stats.norm.cdf(lower[3], eta[3], sd))]
    np.testing.assert_allclose(gq["gaussian_censored"], censored, rtol=1e-10)
    y, n, mu, phi = np.array(OBSERVATIONS["y_int"]), np.array(OBSERVATIONS["trials"]), np.exp(eta), 3.5
    np.testing.assert_allclose(gq["poisson"], stats.poisson.logpmf(y, mu), rtol=1e-10)
    np.testing.assert_allclose(gq["negbinomial"], stats.nbinom.logpmf(y, phi, phi / (phi + mu)), rtol=1e-10)
    p = 1 / (1 + np.exp(-eta))
    np.testing.assert_allclose(gq["binomial"], stats.binom.logpmf(y, n, p), rtol=1e-10)
    np.testing.assert_allclose(gq["response"], p, rtol=1e-12)


def test_latent_emulator_mean_is_the_gp_conditional_mean(gq):
    xt_obs = np.column_stack([X1[:, 0], np.full(6, 0.3)])
    K = se(X2, X2) + 0.01 * np.eye(4)
    expected = 0.2 + se(xt_obs, X2) @ np.linalg.solve(K, RESID[:4] - 0.2)
    np.testing.assert_allclose(gq["emulator_mean_at"], expected, rtol=1e-9)


def test_functional_theta_rows(gq):
    # theta 1 is scalar (0.25 of [0, 1]); theta 2 is logistic(g) of [10, 20] at g = 0 and 2
    expected = [[0.25, 15.0], [0.25, 10 + 10 / (1 + np.exp(-2.0))]]
    np.testing.assert_allclose(gq["theta_rows"], expected, rtol=1e-12)


def test_normal_quadrature_is_gauss_hermite(gq):
    nodes, weights = np.polynomial.hermite_e.hermegauss(20)
    np.testing.assert_allclose(np.sort(gq["quadrature_nodes"]), nodes, atol=1e-10)
    np.testing.assert_allclose(gq["quadrature_weights"][np.argsort(gq["quadrature_nodes"])],
                               weights / np.sqrt(2 * np.pi), rtol=1e-8, atol=1e-14)


def _observation_density(k: int, i: int, eta: float) -> float:
    """p(y_i | eta) of the harness's observation i under likelihood k (gaussian on the standardised scale)."""
    o = OBSERVATIONS
    y, n, sd, phi = o["y_int"][i], o["trials"][i], 0.7, 3.5
    if k == 1:
        lower, upper = o["lower_bound"][i], o["upper_bound"][i]
        return [stats.norm.pdf(o["y_real"][i], eta, sd), stats.norm.cdf(upper, eta, sd),
                stats.norm.sf(lower, eta, sd),
                stats.norm.cdf(upper, eta, sd) - stats.norm.cdf(lower, eta, sd)][o["censoring"][i]]
    mu = np.exp(eta)
    if k == 2:
        return stats.poisson.pmf(y, mu)
    if k == 3:
        return stats.nbinom.pmf(y, phi, phi / (phi + mu))
    return stats.binom.pmf(y, n, 1 / (1 + np.exp(-eta)))


def test_latent_loo_integrates_the_left_out_discrepancy(gq):
    # reference: the GP conditional of delta_i given the others by brute force,
    # and the integral over it by adaptive scipy quadrature
    K = se(X2, X2) + 0.01 * np.eye(4)
    check_latent_loo(K, gq["latent_loo_lik"], gq["latent_loo_mean"], range(1, 5))


def check_latent_loo(K, loo_lik, loo_mean, likelihoods):
    from scipy.integrate import quad

    delta = RESID[:4]
    y_center, y_scale = 0.2, 1.5
    for i in range(4):
        rest = np.delete(np.arange(4), i)
        weights = np.linalg.solve(K[np.ix_(rest, rest)], K[rest, i])
        m, s = weights @ delta[rest], np.sqrt(K[i, i] - K[rest, i] @ weights)
        eta = OBSERVATIONS["eta"][i]
        for k in likelihoods:
            density, _ = quad(lambda u, k=k, i=i, c=eta + m, s=s: _observation_density(k, i, c + s * u)
                              * stats.norm.pdf(u),
                              -12, 12, epsabs=0, epsrel=1e-11, limit=200)
            expected = np.log(density) - (np.log(y_scale) if k == 1 and i == 0 else 0)
            # 20 nodes; the hardest case, a zero count under a wide conditional, is off by 3e-7
            np.testing.assert_allclose(loo_lik[k - 1, i], expected, rtol=1e-6,
                                       err_msg=f"likelihood {k}, observation {i}")
            inverse_link = {1: lambda e: y_center + y_scale * e, 2: np.exp, 3: np.exp,
                            4: lambda e: 1 / (1 + np.exp(-e))}[k]
            mean, _ = quad(lambda u, g=inverse_link, c=eta + m, s=s: g(c + s * u) * stats.norm.pdf(u), -12, 12,
                           epsabs=0, epsrel=1e-11)
            np.testing.assert_allclose(loo_mean[k - 1, i], mean, rtol=1e-6,
                                       err_msg=f"likelihood {k}, observation {i}")


def restricted(K_ab, K_aU, K_Ub, K_UU, A, ridge=0.0):
    """K_ab - K_aU A T^-1 A' K_Ub, T = A' K_UU A + ridge I + the jitter of restriction_cholesky."""
    T = A.T @ K_UU @ A + ridge * np.eye(A.shape[1])
    T += JITTER * np.mean(np.diag(A.T @ K_UU @ A)) * np.eye(A.shape[1])
    return K_ab - K_aU @ A @ np.linalg.solve(T, A.T @ K_Ub)


def test_restricted_gp_cov_at_points_and_new_points(gq):
    A = A_RESTRICT
    np.testing.assert_allclose(gq["restricted_K"], restricted(se(X1, X1), se(X1, X1), se(X1, X1), se(X1, X1), A),
                               rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(gq["restricted_K_cross"],
                               restricted(se(X2, X1), se(X2, X1), se(X1, X1), se(X1, X1), A), rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(gq["restricted_K_new"],
                               restricted(se(X2, X2), se(X2, X1), se(X1, X2), se(X1, X1), A), rtol=1e-7, atol=1e-10)
    # the same restriction as test_orthogonal_gp_covariance's
    np.testing.assert_allclose(gq["restricted_K"], gq["orthogonal_cov"], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(gq["unrestricted_K_cross"], se(X2, X1), rtol=1e-10)


def test_priors(gq):
    from scipy.stats import invgamma, norm

    def n(x, mu, sd):
        return norm.logpdf(np.atleast_1d(x), mu, sd).sum()

    lsc = np.array([0.3, 0.7])
    expected = [invgamma.logpdf(lsc, 3, scale=1).sum(), n([0.5, 2.0], 0, 2), invgamma.logpdf(lsc, 2, scale=1).sum(),
                invgamma.logpdf(lsc, 3, scale=1).sum(), n(0.4, 0, 1), n([0.4, 0.9], 0, 1), n(0.3, 0, 0.5),
                n(1.1, 1, 0.25), n(0.6, 0, 1), n([0.8, 2.0], 0, 1.5),
                n(0.3, 0, 1), n([0.3, -1.2], 0, 1), n(0.5, 0, 1), n([0.5, 1.5], 0, 1), n(0.01, 0, 0.05),
                n([0.01, 0.1], 0, 0.05)]
    np.testing.assert_allclose(gq["priors"], expected, rtol=1e-10)


HS_INDEX, HS_BOUNDARY, HS_LONGEST = np.array([[1, 1], [2, 1], [1, 3]]), np.array([1.5, 1.8]), np.array([0.5, 0.5])


def hs_basis(x):
    out = np.ones((len(x), len(HS_INDEX)))
    for d, L in enumerate(HS_BOUNDARY):
        out *= np.sin(np.pi * HS_INDEX[:, d] / (2 * L) * (x[:, [d]] - 0.5 + L)) / np.sqrt(L)
    return out


def hs_weight_sd(kernel):
    from scipy.special import gammaln

    ell = np.minimum(LS, HS_LONGEST)
    w2 = ((ell * np.pi * HS_INDEX / (2 * HS_BOUNDARY)) ** 2).sum(1)
    dims = 2
    if kernel == "se":
        density = SD**2 * np.prod(ell) * (2 * np.pi) ** (dims / 2) * np.exp(-0.5 * w2)
    else:
        nu = 2.5
        density = (SD**2 * np.prod(ell) * 2**dims * np.pi ** (dims / 2)
                   * np.exp(gammaln(nu + dims / 2) - gammaln(nu)) * (2 * nu) ** nu * (2 * nu + w2) ** -(nu + dims / 2))
    return np.sqrt(density)


def test_hsgp(gq):
    phi = hs_basis(X1)
    np.testing.assert_allclose(gq["hs_basis"], phi, rtol=1e-10)
    np.testing.assert_allclose(gq["hs_sd_se"], hs_weight_sd("se"), rtol=1e-10)
    np.testing.assert_allclose(gq["hs_sd_m52"], hs_weight_sd("m52"), rtol=1e-10)
    for name, sd in (("hs_marginal", hs_weight_sd("se")), ("hs_marginal_sums", hs_weight_sd("m52"))):
        cov = phi @ np.diag(sd**2) @ phi.T + 0.3 * np.eye(6)
        np.testing.assert_allclose(gq[name], stats.multivariate_normal(np.zeros(6), cov).logpdf(RESID), rtol=1e-10)
    # the weights' posterior draw from given normals: W (P^-1 W Phi' r / v + L'^-1 z), P = L L'
    sd, z = hs_weight_sd("se"), np.array([0.1, -0.4, 0.7])
    P = np.eye(3) + np.diag(sd) @ phi.T @ phi @ np.diag(sd) / 0.3
    L = np.linalg.cholesky(P)
    expected = sd * (np.linalg.solve(P, sd * (phi.T @ RESID)) / 0.3 + np.linalg.solve(L.T, z))
    np.testing.assert_allclose(gq["hs_weights"], expected, rtol=1e-10)


def test_hsgp_mirrors_python():
    from stancal.numerics import hsgp

    np.testing.assert_allclose(hsgp.basis(X1, HS_INDEX, HS_BOUNDARY), hs_basis(X1), rtol=1e-12)


def test_chebyshev_tensor_basis(gq):
    from numpy.polynomial import chebyshev

    t1 = [chebyshev.chebval(2 * 0.3 - 1, np.eye(3)[k]) for k in range(3)]
    t2 = [chebyshev.chebval(2 * 0.8 - 1, np.eye(2)[k]) for k in range(2)]
    expected = np.kron(t1, t2)  # the first parameter's index varies slowest
    np.testing.assert_allclose(gq["chebyshev"], expected, rtol=1e-12, atol=1e-15)
    from stancal.numerics.scalable_emulator import chebyshev_basis

    np.testing.assert_allclose(chebyshev_basis(np.array([[0.3, 0.8]]), (2, 1))[0], expected, rtol=1e-12, atol=1e-15)


def test_independent_variance(gq):
    np.testing.assert_allclose(gq["variance_known"], np.square([0.1, 0.2, 0.3]), rtol=1e-14)
    np.testing.assert_allclose(gq["variance_one"], [0.25] * 3, rtol=1e-14)
    np.testing.assert_allclose(gq["variance_per_experiment"], [0.25, 0.49, 0.25], rtol=1e-14)


def test_experiment_simulator(gq):
    theta2 = np.array([0.5, 2.0])[[0, 1, 0]]
    f = np.exp(-THETA_SIM[0] * X_SIM[:, 0]) + theta2 * X_SIM[:, 1] ** 2
    np.testing.assert_allclose(gq["experiment_f"], (f - 0.2) / 1.5, rtol=1e-12)


def se_with(a, b, sd, ls):
    d2 = (((a[:, None, :] - b[None, :, :]) / np.asarray(ls)) ** 2).sum(-1)
    return sd**2 * np.exp(-0.5 * d2)


# the harness's same_point: x2's points 1 and 3 share one nugget draw, as identical points would
SAME_POINT = np.array([[1, 0, 1, 0], [0, 1, 0, 0], [1, 0, 1, 0], [0, 0, 0, 1.0]])


def weights_reference(points, mean, sd, ls, alpha, nugget):
    K_var = se(X1, X1) + 0.1 * np.eye(6)  # the variance runs x1 with se_sym's hyperparameters + 0.1
    K_pv = se_with(points, X1, sd, ls)
    return mean + K_pv @ alpha, (se_with(points, points, sd, ls) + nugget**2 * SAME_POINT
                                 - K_pv @ np.linalg.solve(K_var, K_pv.T))


def test_component_weights(gq):
    mean, cov = weights_reference(X2, 0.2, SD, LS, RESID, nugget=0.3)
    np.testing.assert_allclose(gq["component_mean"], mean, rtol=1e-10)
    np.testing.assert_allclose(gq["component_cov"], cov, rtol=1e-8, atol=1e-10)


def test_weight_gp_factors(gq):
    for c, (mean, sd, ls, nugget) in enumerate([(0.1, SD, LS, 0.05), (-0.2, 0.9, [0.5, 0.6], 0.1)]):
        K = se_with(X1, X1, sd, ls) + (nugget**2 + JITTER * sd**2) * np.eye(6)
        np.testing.assert_allclose(gq["factors_L"][c], np.linalg.cholesky(K), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(gq["factors_alpha"][:, c], np.linalg.solve(K, A_RESTRICT[:, c] - mean), rtol=1e-9)


def test_experiment_weights(gq):
    points = np.column_stack([X2[:, 0], np.full(4, 0.3)])
    K_var = se(X1, X1) + 0.1 * np.eye(6)
    for c, (mean, sd, ls, nugget) in enumerate([(0.2, SD, LS, 0.05), (-0.1, 0.9, [0.5, 0.6], 0.1)]):
        K_pv = se_with(points, X1, sd, ls)
        np.testing.assert_allclose(gq["experiment_means"][:, c], mean + K_pv @ A_RESTRICT[:, c], rtol=1e-10)
        cov = se_with(points, points, sd, ls) + nugget**2 * SAME_POINT - K_pv @ np.linalg.solve(K_var, K_pv.T)
        np.testing.assert_allclose(gq["experiment_covs"][c], cov, rtol=1e-8, atol=1e-10)


def test_signal_cov(gq):
    exp_a, exp_b = np.array([1, 2, 1, 2]) - 1, np.array([2, 1, 1]) - 1
    comp_a = np.array([[1, 0.5], [0.2, -1], [0.3, 0.3], [-0.7, 2]])
    comp_b = np.array([[0.4, 1], [1, 0], [-0.5, 0.5]])
    W = [np.array([[1, 0.3], [0.3, 2]]), np.array([[0.5, -0.1], [-0.1, 0.8]])]
    expected = sum(np.outer(comp_a[:, c], comp_b[:, c]) * W[c][np.ix_(exp_a, exp_b)] for c in range(2))
    expected = expected + se_with(X2, X1[:3], 0.7, [0.4, 0.6])
    np.testing.assert_allclose(gq["signal"], expected, rtol=1e-10)


def test_latent_program_pieces(gq):
    np.testing.assert_allclose(gq["observation_parameters"], [0.7, 1, 4, 1], rtol=1e-14)
    x_fun = X1[:3, :1]
    values = np.array([0.2, -0.5, 1.0])
    K = se_with(x_fun, x_fun, 0.9, [0.4]) + JITTER * 0.81 * np.eye(3)
    np.testing.assert_allclose(gq["functional_prior_centred"],
                               stats.multivariate_normal(np.zeros(3), K).logpdf(values), rtol=1e-10)  # level 0.5
    np.testing.assert_allclose(gq["functional_prior_noncentred"], stats.norm.logpdf([0.3, -1.1, 0.6]).sum(),
                               rtol=1e-10)
    # at the new points: theta 1 stays scalar; theta 2 = logistic(GP draw given its values, normals column 3)
    x_new = X2[:2, :1]
    K_cross, K_new = se_with(x_new, x_fun, 0.9, [0.4]), se_with(x_new, x_new, 0.9, [0.4])
    A = np.linalg.solve(K, K_cross.T)
    cov = K_new - K_cross @ A + JITTER * np.mean(np.diag(K_new)) * np.eye(2)
    draw = A.T @ values + np.linalg.cholesky(cov) @ np.array([0.3, -0.8])
    np.testing.assert_allclose(gq["functional_new"][:, 0], 0.25, rtol=1e-14)
    np.testing.assert_allclose(gq["functional_new"][:, 1], 1 / (1 + np.exp(-draw)), rtol=1e-8)
    assert np.all((gq["functional_grid"] >= 10) & (gq["functional_grid"] <= 20))
    # latent_point_quantities_rng: the latent LOO with delta's prior from latent_gp_cholesky
    K_delta = se(X2, X2) + JITTER * SD**2 * np.eye(4)
    check_latent_loo(K_delta, gq["point_loo_lik"], gq["point_loo_mean"], (1, 2))


def test_latent_gp_centred_and_non_centred(gq):
    """latent_gp_values and latent_gp_prior_lpdf: the values themselves and
    their GP density (centred), or L z and the standard normals' density
    (non-centred), L the Cholesky factor with the jitter."""
    K = se(X2, X2) + JITTER * SD**2 * np.eye(4)
    np.testing.assert_allclose(gq["latent_values_centred"], RESID[:4], rtol=1e-14)
    np.testing.assert_allclose(gq["latent_values_noncentred"], np.linalg.cholesky(K) @ Z_DRAW, rtol=1e-10)
    np.testing.assert_allclose(gq["latent_prior_centred"],
                               stats.multivariate_normal(np.zeros(4), K).logpdf(RESID[:4]), rtol=1e-10)
    np.testing.assert_allclose(gq["latent_prior_noncentred"], stats.norm.logpdf(Z_DRAW).sum(), rtol=1e-10)


def test_given_normals_are_checked(gq):
    import stan

    harness = flatten(HARNESS)
    with pytest.raises((RuntimeError, ValueError), match="must be 0 or 3; got 2"):
        model = stan.build(harness.code, data={**gq["_data"], "needed_count": 3}, random_seed=1)
        model.fixed_param(num_samples=1, num_chains=1)
    for given in (0, 3):  # none given, or one per value needed
        model = stan.build(harness.code, data={**gq["_data"], "given_count": given, "needed_count": 3},
                           random_seed=1)


def test_noise_variances_densities_and_weights(gq):
    variance = NOISE_VAR
    weight, nu = np.array(NOISE["mix_weight"]), NOISE["nu"][0]
    np.testing.assert_allclose(gq["noise_var"], variance, rtol=1e-12)
    np.testing.assert_allclose(gq["noise_var_weighted"], variance / weight, rtol=1e-12)
    scale = np.sqrt(variance)
    np.testing.assert_allclose(gq["noise_ll_normal"], stats.norm.logpdf(RESID, 0, scale), rtol=1e-10)
    np.testing.assert_allclose(gq["noise_ll_t"], stats.t.logpdf(RESID, nu, 0, scale), rtol=1e-10)
    np.testing.assert_allclose(gq["noise_total_normal"], stats.norm.logpdf(RESID, 0, scale).sum(), rtol=1e-10)
    np.testing.assert_allclose(gq["noise_total_t"], stats.t.logpdf(RESID, nu, 0, scale).sum(), rtol=1e-10)
    # E(w | resid) of the scale mixture (Lange, Little & Taylor 1989), and the sampled weights as they are
    np.testing.assert_allclose(gq["noise_row_weight"], (nu + 1) / (nu + RESID**2 / variance), rtol=1e-10)
    np.testing.assert_allclose(gq["noise_row_weight_sampled"], weight, rtol=1e-12)
    np.testing.assert_allclose(gq["noise_weight_density"],
                               stats.gamma.logpdf(weight, nu / 2, scale=2 / nu).sum(), rtol=1e-10)
    np.testing.assert_allclose(gq["noise_dof_density"], stats.gamma.logpdf(nu, 2, scale=10), rtol=1e-10)
