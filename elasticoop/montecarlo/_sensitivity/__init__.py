"""Global sensitivity analysis of a study's results: Sobol' indices (`sobol`),
Morris elementary effects (`morris`), derivative-based measures and their bound on
the total indices (`dgsm`), the indices against the number of samples
(`convergence`), and the designs they need (`design`)."""
