//! A bounce's guide queries, gathered over the wavefront so that the guide answers them in
//! batches: selection probabilities, then samples and densities.

use glam::{Vec2, Vec3};

use crate::guiding::{Guide, GuideSample, GuideVertex, PdfQuery, SampleQuery};

/// The guide queries of one wavefront step: the guided vertices, what the guide prepared for
/// them, and the sample and density queries that refer to them, answered in one batch call each.
pub(super) struct GuideBatch<G: Guide + ?Sized> {
    pub(super) vertices: Vec<GuideVertex>,
    pub(super) prepared: G::Prepared,
    pub(super) alphas: Vec<f32>,
    pub(super) pdf_queries: Vec<PdfQuery>,
    pub(super) pdfs: Vec<f32>,
    pub(super) sample_queries: Vec<SampleQuery>,
    pub(super) samples: Vec<Option<GuideSample>>,
}

impl<G: Guide + ?Sized> GuideBatch<G> {
    pub(super) fn new() -> Self {
        Self {
            vertices: Vec::new(),
            prepared: G::Prepared::default(),
            alphas: Vec::new(),
            pdf_queries: Vec::new(),
            pdfs: Vec::new(),
            sample_queries: Vec::new(),
            samples: Vec::new(),
        }
    }

    /// Add a vertex to the batch; returns its index.
    pub(super) fn push(&mut self, vertex: GuideVertex) -> usize {
        self.vertices.push(vertex);
        self.vertices.len() - 1
    }

    /// Prepare the guide for the batch's vertices and get their selection probabilities.
    pub(super) fn select(&mut self, guide: &G) {
        self.alphas.clear();
        self.alphas.resize(self.vertices.len(), 0.0);
        if !self.vertices.is_empty() {
            guide.prepare(&self.vertices, &mut self.prepared);
            guide.selection_probabilities(&self.vertices, &self.prepared, &mut self.alphas);
        }
        self.pdf_queries.clear();
        self.sample_queries.clear();
    }

    /// Queue the guide's density of `wi` at vertex `vertex`; returns the query's index.
    pub(super) fn pdf(&mut self, vertex: usize, wi: Vec3) -> usize {
        self.pdf_queries.push(PdfQuery { vertex, wi });
        self.pdf_queries.len() - 1
    }

    /// Queue a guide sample at vertex `vertex` from `u`; returns the query's index.
    pub(super) fn sample(&mut self, vertex: usize, u: Vec2) -> usize {
        self.sample_queries.push(SampleQuery { vertex, u });
        self.sample_queries.len() - 1
    }

    /// Answer all queued queries.
    pub(super) fn run(&mut self, guide: &G) {
        self.pdfs.clear();
        self.pdfs.resize(self.pdf_queries.len(), 0.0);
        if !self.pdfs.is_empty() {
            guide.pdf_batch(
                &self.vertices,
                &self.prepared,
                &self.pdf_queries,
                &mut self.pdfs,
            );
        }
        self.samples.clear();
        self.samples.resize(self.sample_queries.len(), None);
        if !self.samples.is_empty() {
            guide.sample_batch(
                &self.vertices,
                &self.prepared,
                &self.sample_queries,
                &mut self.samples,
            );
        }
    }
}
