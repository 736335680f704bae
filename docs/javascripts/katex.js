// Render the maths that pymdownx.arithmatex marks (class "arithmatex") with KaTeX,
// on every page load, including Material's instant navigation (document$).
function renderArithmatex() {
  document.querySelectorAll(".arithmatex").forEach((element) => {
    renderMathInElement(element, {
      delimiters: [
        { left: "\\(", right: "\\)", display: false },
        { left: "\\[", right: "\\]", display: true },
      ],
      throwOnError: false,
    });
  });
}

if (typeof document$ !== "undefined") {
  document$.subscribe(renderArithmatex);
} else {
  document.addEventListener("DOMContentLoaded", renderArithmatex);
}
