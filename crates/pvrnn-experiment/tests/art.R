# An independent computation of the experiments' statistics in base R (no ARTool: CRAN is
# not reachable here), for crates/pvrnn-experiment/tests/against_r.rs.
#
#   Rscript art.R DIR
#
# DIR/two_way.csv: block,a,b,y (a blocked two-factor design, one value per block and cell)
# DIR/one_way.csv: group,y     (independent groups)
# DIR/paired.csv:  x,y         (paired values)
# Prints one "key value" line per statistic.
args <- commandArgs(trailingOnly = TRUE)
dir <- args[1]
out <- function(key, value) cat(key, sprintf("%.12g", value), "\n")

# Pairwise contrasts of the mean ranks `r` between the levels of `group`: t with the
# model's residual mean square `mse` and `df`, Holm-adjusted together (ART-C).
contrasts <- function(prefix, r, group, mse, df) {
  means <- tapply(r, group, mean); counts <- tapply(r, group, length)
  lv <- levels(group); ps <- c(); keys <- c()
  for (i in 1:(length(lv) - 1)) for (j in (i + 1):length(lv)) {
    t <- (means[i] - means[j]) / sqrt(mse * (1 / counts[i] + 1 / counts[j]))
    key <- paste0(prefix, ".", lv[i], "-", lv[j])
    out(paste0(key, ".t"), t)
    ps <- c(ps, 2 * pt(-abs(t), df)); keys <- c(keys, key)
  }
  holm <- p.adjust(ps, "holm")
  for (k in seq_along(ps)) out(paste0(keys[k], ".p_holm"), holm[k])
}

# Two-way aligned rank transform (Wobbrock et al. 2011) with the block as an additive
# factor: align for each effect (residual from the cell means + the effect's estimate),
# rank, then the ANOVA of the full model on those ranks; the effect's own F.
d <- read.csv(file.path(dir, "two_way.csv"))
d$block <- factor(d$block); d$a <- factor(d$a); d$b <- factor(d$b)
cell <- ave(d$y, d$a, d$b)
grand <- mean(d$y)
ma <- ave(d$y, d$a); mb <- ave(d$y, d$b)
aligned <- list(
  a = d$y - cell + (ma - grand),
  b = d$y - cell + (mb - grand),
  "a:b" = d$y - cell + (cell - ma - mb + grand)
)
for (effect in names(aligned)) {
  d$r <- rank(aligned[[effect]])
  fit <- lm(r ~ a * b + block, data = d)
  tab <- anova(fit)
  out(paste0("two_way.F.", effect), tab[effect, "F value"])
  out(paste0("two_way.p.", effect), tab[effect, "Pr(>F)"])
  out(paste0("two_way.df2.", effect), tab["Residuals", "Df"])
  ss <- tab[effect, "Sum Sq"]
  out(paste0("two_way.eta.", effect), ss / (ss + tab["Residuals", "Sum Sq"]))
  if (effect == "a") {
    contrasts("two_way.contrast_a", d$r, d$a, tab["Residuals", "Mean Sq"], tab["Residuals", "Df"])
  }
}
# Cell contrasts (ART-C of a:b): the combined factor, aligned, is the data less a constant.
d$ab <- interaction(d$a, d$b, sep = "/", lex.order = TRUE)
d$r <- rank(d$y)
tab <- anova(lm(r ~ ab + block, data = d))
out("two_way.cells.F", tab["ab", "F value"])
out("two_way.cells.mse", tab["Residuals", "Mean Sq"])

# One-way: the ANOVA of the ranks.
g <- read.csv(file.path(dir, "one_way.csv"))
g$group <- factor(g$group)
g$r <- rank(g$y)
tab <- anova(lm(r ~ group, data = g))
out("one_way.F", tab["group", "F value"])
out("one_way.p", tab["group", "Pr(>F)"])
contrasts("one_way.contrast", g$r, g$group, tab["Residuals", "Mean Sq"], tab["Residuals", "Df"])

# Paired t-test.
p <- read.csv(file.path(dir, "paired.csv"))
tt <- t.test(p$x, p$y, paired = TRUE)
out("paired.t", tt$statistic)
out("paired.p", tt$p.value)
